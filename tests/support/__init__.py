"""What the tests share: ``tiny_slam`` (a tiny synthetic sequence and SLAM config), ``recordings`` (tiny datasets
written to disk in the readers' layouts), ``scenes`` (the rasterizer tests' scenes), ``reference_render`` and
``reference_cbknn`` (the dense float64 references), ``raster_checks`` (tolerances and error metrics against them),
``kill_harness`` (``gsjax run`` killed at traced points, run as a script)."""
