//! Frames as shared memory delivers them: any header (sequence, time, size, format) and any
//! pixels, for both cameras, over a few ticks of the control loop. The contract: the tick
//! never panics; a bad frame is counted and ignored, and every command is finite.
#![no_main]

use dribble_controller::policy::BrightnessPolicy;
use dribble_controller::{
    BottomFrame, CameraInput, ControlLoop, FrameHeader, LoopConfig, ManualClock, TopFrame,
};
use libfuzzer_sys::fuzz_target;

fn u64_at(data: &[u8], at: usize) -> u64 {
    let mut bytes = [0u8; 8];
    for (i, byte) in bytes.iter_mut().enumerate() {
        *byte = data.get(at + i).copied().unwrap_or(0);
    }
    u64::from_le_bytes(bytes)
}

fn header(data: &[u8], at: usize) -> FrameHeader {
    FrameHeader {
        sequence: u64_at(data, at),
        timestamp_ns: u64_at(data, at + 8),
        width: u64_at(data, at + 16) as u32,
        height: (u64_at(data, at + 16) >> 32) as u32,
        format: u64_at(data, at + 24) as u32,
        reserved: (u64_at(data, at + 24) >> 32) as u32,
    }
}

fuzz_target!(|data: &[u8]| {
    let clock = ManualClock::default();
    let mut control = ControlLoop::new(
        LoopConfig::default(),
        BrightnessPolicy::default(),
        clock.clone(),
    );
    let (mut top, mut bottom) = (TopFrame::new_boxed(), BottomFrame::new_boxed());
    // The pixels: the input, repeated.
    if !data.is_empty() {
        for (pixel, byte) in top.as_bytes_mut().iter_mut().zip(data.iter().cycle()) {
            *pixel = *byte;
        }
        for (pixel, byte) in bottom
            .as_bytes_mut()
            .iter_mut()
            .zip(data.iter().rev().cycle())
        {
            *pixel = *byte;
        }
    }
    // Up to 8 ticks, 64 bytes each: two headers, the clock's step, which cameras deliver.
    for (tick, chunk) in data.chunks(64).take(8).enumerate() {
        *top.header_mut() = header(chunk, 0);
        *bottom.header_mut() = header(chunk, 32);
        let delivers = chunk.first().copied().unwrap_or(0);
        let input = CameraInput {
            top: (delivers & 1 != 0).then_some(&*top),
            bottom: (delivers & 2 != 0).then_some(&*bottom),
        };
        let command = control.tick(input);
        let [forward, left, turn] = command.speed.as_array();
        assert!(
            forward.is_finite() && left.is_finite() && turn.is_finite(),
            "tick {tick}"
        );
        clock.advance(std::time::Duration::from_nanos(
            u64_at(chunk, 40) % 1_000_000_000,
        ));
    }
});
