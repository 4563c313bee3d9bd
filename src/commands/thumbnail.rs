//! `dribble thumbnail`: what the policy sees of one raw camera frame.

use std::fs;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, ValueEnum};
use dribble_controller::histogram::intensity_histogram;
use dribble_controller::thumbnail::downscale;
use dribble_controller::{
    BottomFrame, BottomThumbnail, CameraFrame, FrameHeader, Thumbnail, Timestamp, TopFrame,
    TopThumbnail,
};

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Camera {
    /// 640x480 frame, 160x120 thumbnail.
    Top,
    /// 320x240 frame, 80x60 thumbnail.
    Bottom,
}

#[derive(Debug, Args)]
pub struct ThumbnailArgs {
    /// Which camera the frame comes from; it fixes the expected size.
    #[arg(long, value_enum)]
    camera: Camera,
    /// The raw frame: packed YUYV bytes, row-major, no header.
    input: PathBuf,
    /// Where to write the thumbnail (binary PGM, viewable with any image viewer).
    #[arg(long, short)]
    out: PathBuf,
}

pub fn run(args: &ThumbnailArgs) -> anyhow::Result<()> {
    let bytes =
        fs::read(&args.input).with_context(|| format!("reading {}", args.input.display()))?;
    let (pgm, histogram) = match args.camera {
        Camera::Top => thumbnail_of::<640, 480, 160, 120>(&bytes, TopFrame::new_boxed(), || {
            Box::new(TopThumbnail::black())
        }),
        Camera::Bottom => {
            thumbnail_of::<320, 240, 80, 60>(&bytes, BottomFrame::new_boxed(), || {
                Box::new(BottomThumbnail::black())
            })
        }
    }
    .with_context(|| {
        format!(
            "{} is not a {:?} camera frame",
            args.input.display(),
            args.camera
        )
    })?;
    fs::write(&args.out, pgm).with_context(|| format!("writing {}", args.out.display()))?;
    println!("wrote {}", args.out.display());
    let shares: Vec<String> = histogram.iter().map(|s| format!("{s:.3}")).collect();
    println!(
        "histogram (bins 0-50, 51-101, 102-152, 153-203, 204-255): {}",
        shares.join(" ")
    );
    Ok(())
}

fn thumbnail_of<const W: usize, const H: usize, const TW: usize, const TH: usize>(
    bytes: &[u8],
    mut frame: Box<CameraFrame<W, H>>,
    black: impl FnOnce() -> Box<Thumbnail<TW, TH>>,
) -> anyhow::Result<(Vec<u8>, [f32; 5])> {
    let header = FrameHeader::yuyv(0, Timestamp::ZERO, W as u32, H as u32);
    frame.fill_from_yuyv(header, bytes)?;
    let mut thumbnail = black();
    downscale(&frame, &mut thumbnail);
    let mut pgm = format!("P5\n{TW} {TH}\n255\n").into_bytes();
    pgm.extend_from_slice(thumbnail.as_bytes());
    Ok((pgm, intensity_histogram(&thumbnail)))
}
