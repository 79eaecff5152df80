"""A run's folder: which files it holds and when it may be used (:mod:`gsjax.app.run_folder.layout`), its outputs
(:mod:`gsjax.app.run_folder.outputs`), its checkpoints (:mod:`gsjax.app.run_folder.checkpoints`) and the warnings
worded from its per-frame outputs (:mod:`gsjax.app.run_folder.run_warnings`)."""
