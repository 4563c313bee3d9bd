"""The policy contract of DESIGN.md in one place: names, shapes, normalisation, scales."""

TOP_SHAPE = (120, 160)
BOTTOM_SHAPE = (60, 80)

TOP_INPUT = "top"
BOTTOM_INPUT = "bottom"
COMMAND_OUTPUT = "command"
H_INPUT, C_INPUT = "h_in", "c_in"
H_OUTPUT, C_OUTPUT = "h_out", "c_out"

#: The network sees `value * INPUT_SCALE` of each u8 thumbnail pixel.
INPUT_SCALE = 1.0 / 255.0

#: What a normalised command of 1.0 means (DESIGN.md, "Speed command").
COMMAND_SCALE = {"forward_mps": 0.25, "left_mps": 0.15, "turn_radps": 1.0}

OPSET = 17
LSTM_UNITS = 64
DEFAULT_CLUSTERS = 4
HISTOGRAM_BINS = 5

KINDS = ("cnn", "hcnn", "rcnn")
