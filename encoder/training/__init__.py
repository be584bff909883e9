"""Optimizing Gaussians against images: the retraining stage of the encoder and its parts.

``optim`` (the 3DGS rates and Adam groups), ``loss`` (L1 + D-SSIM), ``targets`` (dataset images or
renders of the original), ``loop`` (one fitting loop for every stage), ``prune`` (which patch
Gaussians survive), and the stage modules built on them.
"""
