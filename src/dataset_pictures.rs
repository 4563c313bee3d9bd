//! The pictures `dribble inspect` draws of a dataset: histograms of the commands and phases,
//! and a contact sheet of sample thumbnails.

use std::path::Path;

use dribble_sim::expert::Phase;
use plotters::prelude::*;

use crate::picture::{FONT, Label, draw_png};

pub(crate) const BINS: usize = 20;

pub(crate) const INK: RGBColor = RGBColor(20, 20, 20);

pub(crate) const BAR: RGBColor = RGBColor(31, 119, 180);

/// A sampled row for the contact sheet.
pub(crate) struct Sample {
    pub(crate) seed: u64,
    pub(crate) row: usize,
    pub(crate) phase: u8,
    pub(crate) command: [f32; 3],
    pub(crate) top: Vec<u8>,
    pub(crate) bottom: Vec<u8>,
}

/// Four bar charts: forward, left, turn (20 bins over -1..1) and the phases, rows on the
/// vertical axis.
pub(crate) fn draw_histograms(
    commands: &[[u64; BINS]; 3],
    phases: &[u64; 4],
    path: &Path,
) -> anyhow::Result<()> {
    draw_png(path, (1400, 360), |root| {
        root.fill(&WHITE)?;
        let panels = root.split_evenly((1, 4));
        let titles = [
            "forward speed (normalised)",
            "sideways speed (normalised, + left)",
            "turn speed (normalised, + left)",
        ];
        for ((panel, counts), title) in panels.iter().zip(commands).zip(titles) {
            let max = counts.iter().copied().max().unwrap_or(0).max(1);
            let mut chart = ChartBuilder::on(panel)
                .margin(10)
                .caption(title, (FONT, 17))
                .x_label_area_size(36)
                .y_label_area_size(56)
                .build_cartesian_2d(-1.0f32..1.0f32, 0u64..max + max / 10)?;
            chart
                .configure_mesh()
                .disable_x_mesh()
                .light_line_style(TRANSPARENT)
                .x_desc("command")
                .y_desc("rows")
                .x_labels(5)
                .label_style((FONT, 13))
                .axis_desc_style((FONT, 14))
                .draw()?;
            let width = 2.0 / BINS as f32;
            chart.draw_series(counts.iter().enumerate().map(|(i, &count)| {
                let left = -1.0 + i as f32 * width;
                Rectangle::new(
                    [(left + 0.1 * width, 0), (left + 0.9 * width, count)],
                    BAR.filled(),
                )
            }))?;
        }
        let max = phases.iter().copied().max().unwrap_or(0).max(1);
        let mut chart = ChartBuilder::on(&panels[3])
            .margin(10)
            .caption("expert phase", (FONT, 17))
            .x_label_area_size(36)
            .y_label_area_size(56)
            // A segmented axis over 0..=3: one segment per phase.
            .build_cartesian_2d(
                (0..Phase::ALL.len() - 1).into_segmented(),
                0u64..max + max / 10,
            )?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .light_line_style(TRANSPARENT)
            .y_desc("rows")
            .x_label_formatter(&|value| match value {
                SegmentValue::CenterOf(i) => Phase::ALL.get(*i).map_or("", |p| p.name()).into(),
                _ => String::new(),
            })
            .label_style((FONT, 13))
            .axis_desc_style((FONT, 14))
            .draw()?;
        chart.draw_series(phases.iter().enumerate().map(|(i, &count)| {
            let mut bar = Rectangle::new(
                [
                    (SegmentValue::Exact(i), 0),
                    (SegmentValue::Exact(i + 1), count),
                ],
                BAR.filled(),
            );
            bar.set_margin(0, 0, 12, 12);
            bar
        }))?;
        Ok(())
    })
}

/// Sample rows: the top thumbnail, the bottom one beside it, and the labels
/// `seed/row phase` and the expert's command.
pub(crate) fn draw_contact_sheet(samples: &[Sample], path: &Path) -> anyhow::Result<()> {
    let (cell_width, cell_height) = (250i32, 164i32);
    let columns = 4;
    let rows = samples.len().div_ceil(columns).max(1) as i32;
    let size = (
        (columns as i32 * cell_width) as u32,
        (rows * cell_height) as u32,
    );
    draw_png(path, size, |root| {
        root.fill(&RGBColor(250, 250, 250))?;
        for (i, sample) in samples.iter().enumerate() {
            let x = (i % columns) as i32 * cell_width + 4;
            let y = (i / columns) as i32 * cell_height + 4;
            for (j, &p) in sample.top.iter().enumerate() {
                let (column, row) = ((j % 160) as i32, (j / 160) as i32);
                root.draw_pixel((x + column, y + row), &RGBColor(p, p, p))?;
            }
            for (j, &p) in sample.bottom.iter().enumerate() {
                let (column, row) = ((j % 80) as i32, (j / 80) as i32);
                root.draw_pixel((x + 164 + column, y + row), &RGBColor(p, p, p))?;
            }
            let phase = Phase::ALL
                .get(usize::from(sample.phase))
                .map_or("?", |p| p.name());
            let [f, l, t] = sample.command;
            root.draw(&Label::new(
                format!("seed {} row {}: {phase}", sample.seed, sample.row),
                (x, y + 123),
                13.0,
                INK,
            ))?;
            root.draw(&Label::new(
                format!("fwd {f:+.2}  left {l:+.2}  turn {t:+.2}"),
                (x, y + 139),
                13.0,
                INK,
            ))?;
        }
        Ok(())
    })
}
