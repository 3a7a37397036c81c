"""rgb2cloud HTTP service: /depth and /pointcloud from a versioned exported generator.

Imports no torch on the ONNX path; the TorchScript backend needs the ``train`` extra.
"""
