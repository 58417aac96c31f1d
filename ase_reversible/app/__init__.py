"""Applications built on the integrator: ready-made systems, the flipbook,
scenes, the demo and the command line.

The app imports the core, never the reverse: no core module imports this
package.  Two doors reach in from the package itself: its ``__init__``
re-exports :class:`~ase_reversible.Flipbook`, and ``__main__`` runs
:func:`ase_reversible.app.cli.main` (``tests/test_app.py`` holds both
rules)."""
