"""Loaded models: the registry that reads models/*/manifest.json and the ONNX sessions.

This layer implements the pipeline's model Protocols (`service.pipeline.types`) with
onnxruntime; the pipeline itself never imports it.
"""
