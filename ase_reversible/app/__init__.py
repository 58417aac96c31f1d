"""Applications built on the integrator: ready-made systems, the flipbook,
scenes, the demo and the command line.  Nothing in the core imports this."""
