"""``gsjax sweep``: the grid of configs and their batches (:mod:`gsjax.app.sweep.grid`), devices and processes
(:mod:`gsjax.app.sweep.devices`) and ``--resume`` (:mod:`gsjax.app.sweep.resume`)."""
