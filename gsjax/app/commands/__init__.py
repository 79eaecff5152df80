"""The ``gsjax`` subcommands, one module each: ``add(subparsers)`` declares its flags, ``run(args)`` runs it.

:mod:`~gsjax.app.commands.common` holds what they share (argument types, the common flags, opening a run's sequence).
"""
