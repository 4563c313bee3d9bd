//! The paper's trajectory figure, drawn with `plotters`: the field to scale (its lines, goals
//! and border) with axes in metres, every episode's robot path (thin) and ball path (thick)
//! in its colour, the robot's start pose (a disc with a heading line), the ball's start (a
//! ring) and its end (a disc, a large one for a goal), and a legend of seed, outcome and time.

use std::f32::consts::TAU;
use std::path::Path;

use dribble_sim::dataset::Outcome;
use dribble_sim::field::FieldGeometry;
use dribble_sim::runner::EpisodeResult;
use glam::Vec2;
use plotters::prelude::*;

use crate::picture::{FONT, Label, draw_png};

/// Distinct colours for episodes, in turn (matplotlib's tab10, white swapped for black).
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(23, 190, 207),
    RGBColor(255, 127, 14),
    RGBColor(227, 119, 194),
    RGBColor(140, 86, 75),
    RGBColor(188, 189, 34),
    RGBColor(30, 30, 30),
    RGBColor(255, 255, 255),
];
const CARPET: RGBColor = RGBColor(60, 140, 70);
const LINE: RGBColor = RGBColor(240, 240, 240);
const GOAL: RGBColor = RGBColor(250, 220, 40);
const INK: RGBColor = RGBColor(20, 20, 20);

/// Pixels per metre of field.
const SCALE: f32 = 80.0;
/// Space around the field's plot: margin, axis label areas, legend rows.
const MARGIN: u32 = 12;
const Y_LABELS: u32 = 60;
const X_LABELS: u32 = 50;
const TITLE_HEIGHT: u32 = 34;
const LEGEND_ROW: u32 = 24;
const LEGEND_COLUMNS: usize = 4;

fn colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// The legend's text for one episode.
fn label(result: &EpisodeResult) -> String {
    match result.outcome {
        Outcome::Goal => format!(
            "seed {}: goal in {:.0} s",
            result.setup.seed, result.duration_s
        ),
        other => format!(
            "seed {}: {} ({:.0} s)",
            result.setup.seed,
            other.name().replace('_', " "),
            result.duration_s
        ),
    }
}

/// The figure's title: who drove (`driver` as `dribble eval --driver` takes it: `expert`
/// or a policy's `policy.toml`), the goals and the seeds.
/// The plot's title: the driver (a policy by its directory's name: a whole path would push
/// the figures off the picture's edge), the goals with their Wilson interval, the seeds, and
/// the conditions when they are not clean.
pub fn title(driver: &str, results: &[EpisodeResult]) -> String {
    let driver = match driver {
        "expert" => "the scripted expert".to_owned(),
        policy => {
            let path = std::path::Path::new(policy);
            let directory = if path.extension().is_some_and(|e| e == "toml") {
                path.parent()
            } else {
                Some(path)
            };
            let name = directory
                .and_then(|d| d.file_name())
                .map_or_else(|| policy.to_owned(), |n| n.to_string_lossy().into_owned());
            format!("policy {name}")
        }
    };
    let goals = results
        .iter()
        .filter(|r| r.outcome == Outcome::Goal)
        .count();
    let (low, high) = crate::evaluation::goal_rate::wilson_interval(goals, results.len());
    let seeds = match (results.first(), results.last()) {
        (Some(first), Some(last)) => {
            format!(", seeds {}..{}", first.setup.seed, last.setup.seed)
        }
        _ => String::new(),
    };
    let conditions = results
        .first()
        .map(|r| r.setup.conditions)
        .filter(|c| !c.is_clean())
        .map_or_else(String::new, |c| format!(", {c}"));
    format!(
        "{driver}: {goals} of {} goals ({low:.2}-{high:.2}){seeds}{conditions}",
        results.len()
    )
}

/// Points around a circle, closed.
fn ring(centre: Vec2, radius: f32) -> Vec<(f32, f32)> {
    (0..=48)
        .map(|i| {
            let angle = i as f32 / 48.0 * TAU;
            (
                centre.x + radius * angle.cos(),
                centre.y + radius * angle.sin(),
            )
        })
        .collect()
}

/// Writes the figure for `results` to `path` (PNG), `title` above the field.
pub fn plot_trajectories(
    results: &[EpisodeResult],
    title: &str,
    path: &Path,
) -> anyhow::Result<()> {
    let field = FieldGeometry::SPL;
    let carpet = Vec2::new(
        field.length / 2.0 + field.border,
        field.width / 2.0 + field.border,
    );
    let half = view_half_extent(
        results
            .iter()
            .flat_map(|r| r.robot_path.iter().chain(&r.ball_path)),
        carpet,
    );
    let plot_width = (2.0 * half.x * SCALE).round() as u32;
    let plot_height = (2.0 * half.y * SCALE).round() as u32;
    // One row for the key to the marks, then the episodes.
    let legend_rows = 1 + results.len().div_ceil(LEGEND_COLUMNS) as u32;
    let chart_height = plot_height + X_LABELS + 2 * MARGIN;
    let size = (
        plot_width + Y_LABELS + 2 * MARGIN,
        TITLE_HEIGHT + chart_height + legend_rows * LEGEND_ROW + MARGIN,
    );
    draw_png(path, size, |root| {
        root.fill(&WHITE)?;
        let (title_area, rest) = root.split_vertically(TITLE_HEIGHT);
        title_area.draw(&Label::new(title, (MARGIN as i32, 8), 22.0, INK).bold())?;
        // The plot area is exactly the field's pixels, so metres are square.
        let (upper, legend) = rest.split_vertically(chart_height);
        let mut chart = ChartBuilder::on(&upper)
            .margin(MARGIN)
            .x_label_area_size(X_LABELS)
            .y_label_area_size(Y_LABELS)
            .build_cartesian_2d(-half.x..half.x, -half.y..half.y)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("x (m)")
            .y_desc("y (m)")
            .x_labels(12)
            .y_labels(9)
            .label_style((FONT, 15))
            .axis_desc_style((FONT, 17))
            .draw()?;
        draw_field(&mut chart, &field, carpet)?;
        for (i, result) in results.iter().enumerate() {
            draw_episode(&mut chart, result, colour(i))?;
        }

        legend.draw(&Label::new(
            "thin: robot path, thick: ball path; disc and tick: robot start and heading; \
             ring: ball start; dot: ball end (large: goal)",
            (MARGIN as i32, 2),
            14.0,
            RGBColor(90, 90, 90),
        ))?;
        let column_width = (size.0 - 2 * MARGIN) as i32 / LEGEND_COLUMNS as i32;
        for (i, result) in results.iter().enumerate() {
            let x = MARGIN as i32 + (i % LEGEND_COLUMNS) as i32 * column_width;
            let y = (1 + i / LEGEND_COLUMNS) as i32 * LEGEND_ROW as i32 + 4;
            legend.draw(&Rectangle::new([(x, y), (x + 14, y + 14)], INK.filled()))?;
            legend.draw(&Rectangle::new(
                [(x + 1, y + 1), (x + 13, y + 13)],
                colour(i).filled(),
            ))?;
            legend.draw(&Label::new(label(result), (x + 20, y - 1), 15.0, INK))?;
        }
        Ok(())
    })
}

type FieldChart<'a, 'b> = ChartContext<
    'a,
    BitMapBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf32, plotters::coord::types::RangedCoordf32>,
>;

/// Half the width and height of the area plotted: the carpet's (`carpet`), grown to take in
/// every robot and ball position (`positions`) with a margin. plotters does not clip a path to the plotting
/// area, so a robot that walked off the carpet would otherwise be drawn over the axes and
/// into the figure's margins; now the figure shows the floor beyond the carpet, in white.
fn view_half_extent<'a>(positions: impl Iterator<Item = &'a Vec2>, carpet: Vec2) -> Vec2 {
    const MARGIN_M: f32 = 0.2;
    positions
        .filter(|p| p.is_finite())
        .fold(carpet, |half, p| half.max(p.abs() + MARGIN_M))
}

/// Carpet (half its size `carpet`), lines (boundary, centre line and circle, goal and penalty
/// areas) and goals.
fn draw_field(
    chart: &mut FieldChart<'_, '_>,
    field: &FieldGeometry,
    carpet: Vec2,
) -> anyhow::Result<()> {
    chart.draw_series([Rectangle::new(
        [(-carpet.x, -carpet.y), (carpet.x, carpet.y)],
        CARPET.filled(),
    )])?;
    let line = LINE.stroke_width(2);
    chart.draw_series(field.line_polylines(48).into_iter().map(|points| {
        PathElement::new(points.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>(), line)
    }))?;
    for side in [-1.0f32, 1.0] {
        let [(x, left), (_, right)] = field.goal_post_centres(side);
        chart.draw_series([PathElement::new(
            vec![(x, left), (x, right)],
            GOAL.stroke_width(5),
        )])?;
        chart.draw_series(
            [left, right]
                .into_iter()
                .map(|y| Circle::new((x, y), 5, GOAL.filled())),
        )?;
    }
    Ok(())
}

/// One episode: paths, start pose, ball start and end.
fn draw_episode(
    chart: &mut FieldChart<'_, '_>,
    result: &EpisodeResult,
    colour: RGBColor,
) -> anyhow::Result<()> {
    let points = |path: &[Vec2]| path.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>();
    chart.draw_series([PathElement::new(
        points(&result.robot_path),
        colour.stroke_width(2),
    )])?;
    chart.draw_series([PathElement::new(
        points(&result.ball_path),
        colour.stroke_width(4),
    )])?;
    let start = result.setup.robot;
    let heading = Vec2::new(start.theta.cos(), start.theta.sin()) * 0.35;
    chart.draw_series([
        PathElement::new(
            vec![
                (start.x, start.y),
                (start.x + heading.x, start.y + heading.y),
            ],
            colour.stroke_width(4),
        ),
        PathElement::new(ring(result.setup.ball, 0.09), colour.stroke_width(2)),
    ])?;
    chart.draw_series([
        Circle::new((start.x, start.y), 10, INK.filled()),
        Circle::new((start.x, start.y), 8, colour.filled()),
    ])?;
    if let Some(end) = result.ball_path.last() {
        let radius = if result.outcome == Outcome::Goal {
            9
        } else {
            5
        };
        chart.draw_series([
            Circle::new((end.x, end.y), radius + 1, INK.filled()),
            Circle::new((end.x, end.y), radius, colour.filled()),
        ])?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_view_is_the_carpet_until_a_path_leaves_it() {
        let carpet = Vec2::new(5.2, 3.7);
        let inside = [Vec2::new(-5.0, 3.0), Vec2::new(0.0, -3.4)];
        assert_eq!(view_half_extent(inside.iter(), carpet), carpet);
        // A robot 6 m from the centre line and 4.1 m to the right: the view takes it in,
        // with the margin, on every side (the field stays centred).
        let off = [Vec2::new(0.0, 0.0), Vec2::new(-6.0, -4.1)];
        let half = view_half_extent(off.iter(), carpet);
        assert!(
            (half.x - 6.2).abs() < 1e-5 && (half.y - 4.3).abs() < 1e-5,
            "{half}"
        );
        // A position that is not a number does not blow the view up.
        let broken = [Vec2::new(f32::NAN, 1.0)];
        assert_eq!(view_half_extent(broken.iter(), carpet), carpet);
    }
}
