//! The paper's trajectory figure: every episode's robot and ball paths on the field, with
//! a legend of seeds and outcomes below.

use std::path::Path;

use dribble_sim::dataset::Outcome;
use dribble_sim::field::FieldGeometry;
use dribble_sim::image_output::RgbImage;
use dribble_sim::runner::EpisodeResult;
use dribble_sim::text::line_height;
use dribble_sim::top_view::FieldCanvas;

/// Distinct colours for episodes, in turn.
const PALETTE: [[u8; 3]; 10] = [
    [31, 119, 180],
    [214, 39, 40],
    [148, 103, 189],
    [23, 190, 207],
    [255, 127, 14],
    [227, 119, 194],
    [140, 86, 75],
    [188, 189, 34],
    [30, 30, 30],
    [255, 255, 255],
];
const BACKGROUND: [u8; 3] = [250, 250, 250];
const INK: [u8; 3] = [20, 20, 20];

/// Draws each episode in its colour: the robot's path thin, the ball's path thick, the
/// robot's start as a disc with a heading tick, the ball's start as a ring, and the ball's
/// end as a disc (a large one for a goal). `title` goes above the legend.
pub fn plot_trajectories(
    results: &[EpisodeResult],
    title: &str,
    path: &Path,
) -> anyhow::Result<()> {
    let field = FieldGeometry::SPL;
    let mut canvas = FieldCanvas::new(&field, 80.0);
    for (i, result) in results.iter().enumerate() {
        let colour = PALETTE[i % PALETTE.len()];
        canvas.path(&result.robot_path, 0.02, colour);
        canvas.path(&result.ball_path, 0.05, colour);
        canvas.robot(result.setup.robot, colour);
        canvas.circle(result.setup.ball, 0.09, 0.03, colour);
        if let Some(end) = result.ball_path.last() {
            let radius = if result.outcome == Outcome::Goal {
                0.12
            } else {
                0.06
            };
            canvas.disc(*end, radius, colour);
        }
    }
    let field_image = canvas.into_image();
    let scale = 2;
    let row = line_height(scale) as u32;
    let columns = 4;
    let legend_rows = results.len().div_ceil(columns) as u32;
    let mut image = RgbImage::filled(
        field_image.width,
        field_image.height + row * (legend_rows + 2) + 8,
        BACKGROUND,
    );
    image.pixels[..field_image.pixels.len()].copy_from_slice(&field_image.pixels);
    let top = i64::from(field_image.height) + 6;
    image.text(8, top, title, scale, INK);
    let column_width = i64::from(image.width) / columns as i64;
    for (i, result) in results.iter().enumerate() {
        let x = 8 + (i % columns) as i64 * column_width;
        let y = top + i64::from(row) * (1 + (i / columns) as i64);
        image.fill_rect(x, y, 14, 14, INK);
        image.fill_rect(x + 1, y + 1, 12, 12, PALETTE[i % PALETTE.len()]);
        let label = match result.outcome {
            Outcome::Goal => format!("{} GOAL {:.0}S", result.setup.seed, result.duration_s),
            other => format!("{} {}", result.setup.seed, other.name()),
        };
        image.text(x + 20, y, &label, scale, INK);
    }
    image.save_png(path)?;
    Ok(())
}
