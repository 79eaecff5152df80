"""One session for every run: frames from a source (a recording, a live camera) through one loop into one recorder.

* :mod:`gsjax.app.session.loop`: the host loop over chunks (read-ahead, timing, capacity growth, the devices' hooks),
  for one config or a batch of configs over the same frames;
* :mod:`gsjax.app.session.recorder`: what one run writes as it goes (per-frame outputs, kept frames, timings,
  checkpoints) and at its end;
* :mod:`gsjax.app.session.runner`: ``gsjax run`` on a recording and its ``--resume``;
  :mod:`gsjax.app.session.live`: on a live camera (:mod:`gsjax.app.session.camera`), or a recording played as one.
"""
