"""The policy contract of DESIGN.md in one place: names, shapes, normalisation, scales."""

TOP_SHAPE = (120, 160)
BOTTOM_SHAPE = (60, 80)

TOP_INPUT = "top"
BOTTOM_INPUT = "bottom"
COMMAND_OUTPUT = "command"
#: The last command sent, `[1, 3]`, for a network that reads it (`[inputs] previous`).
PREVIOUS_INPUT = "previous"
H_INPUT, C_INPUT = "h_in", "c_in"
H_OUTPUT, C_OUTPUT = "h_out", "c_out"

#: The network sees `value * INPUT_SCALE` of each u8 thumbnail pixel.
INPUT_SCALE = 1.0 / 255.0

#: A standardised policy (`[normalisation] standardise = true`) sees each thumbnail as
#: `(pixel - mean) / max(spread, STANDARDISE_FLOOR_LEVELS)` over that thumbnail's own pixels,
#: in pixel levels (the controller's `policy::network_input`).
STANDARDISE_FLOOR_LEVELS = 4.0


def network_input(thumbnails, standardise: bool = False, scale: float = INPUT_SCALE):
    """u8 thumbnails [..., H, W] -> the f32 values the controller feeds the network, as the
    manifest's normalisation says: `pixel * scale`, or standardised per thumbnail with the
    controller's arithmetic (integer sums, float64 statistics, float32 values)."""
    import numpy as np

    pixels = np.asarray(thumbnails, dtype=np.uint8)
    if not standardise:
        return pixels.astype(np.float32) * np.float32(scale)
    count = pixels.shape[-1] * pixels.shape[-2]
    sums = pixels.sum(axis=(-2, -1), dtype=np.uint64).astype(np.float64)
    squares = (pixels.astype(np.uint64) ** 2).sum(axis=(-2, -1), dtype=np.uint64).astype(np.float64)
    mean = sums / count
    spread = np.maximum(np.sqrt(np.maximum(squares / count - mean * mean, 0.0)), STANDARDISE_FLOOR_LEVELS)
    mean32 = mean.astype(np.float32)[..., None, None]
    inverse32 = (1.0 / spread).astype(np.float32)[..., None, None]
    return (pixels.astype(np.float32) - mean32) * inverse32

#: What a normalised command of 1.0 means (DESIGN.md, "Speed command").
COMMAND_SCALE = {"forward_mps": 0.25, "left_mps": 0.15, "turn_radps": 1.0}

OPSET = 17
LSTM_UNITS = 64
DEFAULT_CLUSTERS = 4
HISTOGRAM_BINS = 5

KINDS = ("cnn", "hcnn", "rcnn")
