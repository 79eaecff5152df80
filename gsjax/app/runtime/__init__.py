"""The process's runtime: JAX's persistent compilation cache (:mod:`gsjax.app.runtime.cache`) and the SLAM program's
exported form beside it (:mod:`gsjax.app.runtime.programs`), the developers' compile log
(:mod:`gsjax.app.runtime.compile_log`), the allocator's arenas (:mod:`gsjax.app.runtime.memory`) and the progress bar
(:mod:`gsjax.app.runtime.progress`)."""
