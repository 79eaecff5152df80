"""Configs' shared machinery: each field declared once with its unit, bounds and whether it is static
(:mod:`gsjax.config.fields`), the text codec of the command line's dotted overrides and of ``config.json``
(:mod:`gsjax.config.text`), and the names users type (:mod:`gsjax.config.names`). The configs themselves live with
what they configure (:class:`gsjax.raster.RasterSettings`, :class:`gsjax.slam.config.SlamConfig`)."""
