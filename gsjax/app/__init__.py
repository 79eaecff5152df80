"""The imperative shell around the pure core: everything that touches files, processes, devices or the terminal.

* :mod:`gsjax.app.cli`: the ``gsjax`` command line, one module per command (``gsjax.app.cli.run``, ...), what they
  share in :mod:`gsjax.app.cli.common`.
* :mod:`gsjax.app.runner`: ``gsjax run``'s driver (chunks, checkpoints, resume, warnings);
  :mod:`gsjax.app.checkpoints`: the checkpoint files; :mod:`gsjax.app.run_dir`: when an output folder may be used;
  :mod:`gsjax.app.run_outputs`: evaluation and the output files of a run.
* :mod:`gsjax.app.sweep` (:mod:`gsjax.app.sweep_devices`: devices and processes): ``gsjax sweep``.
* :mod:`gsjax.app.landscape`: ``gsjax landscape``; :mod:`gsjax.app.bench`: ``gsjax bench``.
* :mod:`gsjax.app.progress`: the progress bar; :mod:`gsjax.app.compilation_cache`: JAX's persistent cache.

The core (``gsjax.camera``, ``gaussians``, ``raster``, ``slam``, ``data``, ``eval``, ``io``, ``report``) never imports
this package.
"""
