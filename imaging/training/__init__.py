"""Optimizing Gaussians against images: the parts every training loop shares.

``optim`` (the 3DGS rates and Adam groups), ``loss`` (L1 + D-SSIM), ``targets`` (dataset images or
renders of the original), ``loop`` (one fitting loop for every stage, with parts of the scene
frozen), ``checkpoint`` (atomic, fingerprinted saves of a run) and ``densify`` (adaptive density
control for vanilla training). The encoder's retraining stage (``spcodec.encoder.retraining``) builds
on them with its own pruning and quantization-aware parts.
"""
