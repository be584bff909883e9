"""Retraining the pruned patch (``EncoderConfig.retrain``): everything between pruning and the
patch layers the file stores.

- :mod:`.stage`: :class:`~.stage.RetrainStage`, the optimization itself (retrain with the sketch
  frozen, quantize, the quantization-aware finish, ranking);
- :mod:`.quantaware`: the models that train through codebooks (snapping, the finish);
- :mod:`.nested`: nested retraining, every layer prefix a trained scene;
- :mod:`.run`: one run of them in order, asking :mod:`spcodec.encoder.sizing` how many to keep;
- :mod:`.targets`: the images trained against; :mod:`.clock`: how long it still takes;
- :mod:`.control`: :class:`~.control.RunControl`, device, checkpoints and stop requests.

Nothing is imported here, so ``spcodec.encoder.retraining.control`` loads without the rest.
"""
