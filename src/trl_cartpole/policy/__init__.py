"""A trained policy: loaded from a checkpoint with its env, exported (ONNX, torch.export), rendered
to a video.
"""
