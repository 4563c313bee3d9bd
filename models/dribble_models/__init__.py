"""dribble's policies: the paper's CNN, hierarchical CNN and recurrent CNN in PyTorch, their
gating, and the export to the ONNX files and `policy.toml` manifests the robot loads.

The contracts (input names and shapes, normalisation, manifest fields) are those of
`shared/DESIGN.md`, section "Policies".
"""
