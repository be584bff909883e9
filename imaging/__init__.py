"""The picture tools of spcodec (extra ``encoder``): what renders, trains and judges pictures.

The encoder's retraining, ``spcodec eval`` and ``spcodec render`` all use them; the decoder and
the format layer never do (``import spcodec.decoder`` loads none of this). Modules:

* :mod:`.cameras` (numpy only) the one camera type; :mod:`.views` cameras sampled around a bare
  PLY; :mod:`.datasets` COLMAP, ``transforms.json`` and LLFF loaders;
* :mod:`.render` the differentiable renderer (PyTorch on the CPU, gsplat on CUDA);
  :mod:`.importance` how much each Gaussian contributes to rendered views;
* :mod:`.images` PNG/JPEG I/O and contact sheets; :mod:`.metrics` PSNR, SSIM, LPIPS;
  :mod:`.evaluate` a decoded scene judged against a reference PLY or a dataset's test images.

Submodules are imported on use; importing this package loads neither torch nor scikit-learn.
"""
