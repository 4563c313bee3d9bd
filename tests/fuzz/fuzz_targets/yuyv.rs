//! Raw YUYV dumps as `dribble thumbnail` reads them: any bytes, of any length, for both
//! cameras. The contract: a frame of the wrong size is an error naming the sizes; one of the
//! right size becomes a thumbnail and a histogram that sums to 1.
#![no_main]

use dribble_controller::histogram::intensity_histogram;
use dribble_controller::thumbnail::downscale;
use dribble_controller::{
    BottomFrame, BottomThumbnail, FrameHeader, Timestamp, TopFrame, TopThumbnail,
};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // Short inputs stand for whole frames by repetition, so right-sized frames occur too.
    let mut frame = TopFrame::new_boxed();
    let header = FrameHeader::yuyv(0, Timestamp::ZERO, 640, 480);
    let bytes: Vec<u8> = match data.split_first() {
        Some((&0, rest)) if !rest.is_empty() => {
            rest.iter().cycle().take(640 * 480 * 2).copied().collect()
        }
        _ => data.to_vec(),
    };
    if frame.fill_from_yuyv(header, &bytes).is_ok() {
        let mut thumbnail = Box::new(TopThumbnail::black());
        downscale(&frame, &mut thumbnail);
        let sum: f32 = intensity_histogram(&thumbnail).iter().sum();
        assert!((sum - 1.0).abs() < 1e-4);
    }
    let mut frame = BottomFrame::new_boxed();
    let header = FrameHeader::yuyv(0, Timestamp::ZERO, 320, 240);
    if frame.fill_from_yuyv(header, data).is_ok() {
        let mut thumbnail = Box::new(BottomThumbnail::black());
        downscale(&frame, &mut thumbnail);
        let sum: f32 = intensity_histogram(&thumbnail).iter().sum();
        assert!((sum - 1.0).abs() < 1e-4);
    }
});
