"""The imperative shell around the pure core: everything that touches files, processes, devices or the terminal.

* :mod:`gsjax.app.cli`: the ``gsjax`` command line, one module per command (``gsjax.app.cli.run``, ...), what they
  share in :mod:`gsjax.app.cli.common`.
* :mod:`gsjax.app.session`: one loop and one recorder for every run (a recording, its resume, a live camera, a
  sweep's configs).
* :mod:`gsjax.app.run_folder`: a run's folder (its files, outputs, checkpoints, warnings).
* :mod:`gsjax.app.sweep`: ``gsjax sweep`` (the grid, devices and processes, resume).
* :mod:`gsjax.app.runtime`: the compilation cache and exported programs, memory, the progress bar.
* :mod:`gsjax.app.landscape`: ``gsjax landscape``; :mod:`gsjax.app.bench`: ``gsjax bench``;
  :mod:`gsjax.app.config_reference` and :mod:`gsjax.app.metrics_reference`: the generated reference pages.

The core (``gsjax.camera``, ``gaussians``, ``raster``, ``slam``, ``data``, ``eval``, ``io``, ``report``) never imports
this package.
"""
