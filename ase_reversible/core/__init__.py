"""The exact engine: fixed-point variables, plans of exact sub-steps,
compositions, and the engine that runs a plan forwards and backwards.

Nothing here knows about ASE.  A dynamics is declared as named
:class:`~.variables.ExactVariable` objects and a palindromic scheme of
:class:`~.plans.SubStep` objects; :class:`~.engine.Engine` does the rest.
"""
