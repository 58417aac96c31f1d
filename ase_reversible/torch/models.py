"""Two energy models for :class:`~ase_reversible.torch.TorchCalculator`.

Both take ``forward(positions, numbers, cell, edge_index, edge_shift)``
(Å, Å, pairs from :func:`~ase_reversible.torch.neighbour_list`) and return
the energy in eV as a scalar float64 tensor.  Each unordered pair is
summed once: of the two directions of a pair only ``i < j`` is kept (for
an atom and its own image, the image whose first non-zero shift component
is positive), which halves the work of the forces and of the products.
"""

from __future__ import annotations

import math

import torch


def half_pairs(edge_index, edge_shift):
    """The edges that carry each unordered pair once: a bool mask
    ``[n_edges]``.  ``edge_index`` holds both directions of every pair
    (:func:`~ase_reversible.torch.neighbour_list`); the shift of one
    direction is exactly minus the other's."""
    i, j = edge_index
    s = edge_shift
    first = torch.where(s[:, 0] != 0, s[:, 0],
                        torch.where(s[:, 1] != 0, s[:, 1], s[:, 2]))
    return (i < j) | ((i == j) & (first > 0))


def pair_distances(positions, edge_index, edge_shift, mask):
    """``r`` per kept edge, Å: ``|x_j - x_i + shift|`` summed in a fixed
    order (the same distance the neighbour list kept the pair by)."""
    i, j = edge_index[:, mask]
    d = (positions[j] - positions[i]) + edge_shift[mask]
    return torch.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
                      + d[:, 2] * d[:, 2])


class LennardJones(torch.nn.Module):
    """The package's smoothly cut-off Lennard-Jones pair potential in torch.

    The same pair energy as :class:`ase_reversible.LennardJones` (with
    ``s = sigma / r``, ``t = (r - ro) / (rc - ro)``)::

        u(r) = 4 epsilon (s**12 - s**6) S(t),  S(t) = 1 - t**3 (10 - 15 t + 6 t**2)

    Parameters
    ----------
    epsilon : float
        Well depth, eV (a trainable parameter).
    sigma : float
        Å (a trainable parameter).
    rc : float, optional
        Cut-off, Å.  Default ``3 * sigma`` (of the initial ``sigma``).
    ro : float, optional
        Where the switch starts, Å.  Default ``0.66 * rc``.

    Unlike the numpy calculator's defaults, ``rc`` and ``ro`` are fixed
    lengths once made: they do not follow ``sigma`` when it is trained
    (the calculator's neighbour list must reach ``rc``).  Compare with
    ``ase_reversible.LennardJones(..., rc=rc, ro=ro)`` given explicitly.
    """

    def __init__(self, epsilon: float = 1.0, sigma: float = 1.0,
                 rc: float | None = None, ro: float | None = None):
        super().__init__()
        rc = 3.0 * sigma if rc is None else float(rc)
        ro = 0.66 * rc if ro is None else float(ro)
        if not 0 <= ro < rc:
            raise ValueError(f'Need 0 <= ro < rc, got ro={ro!r}, rc={rc!r} '
                             '(Å)')
        self.epsilon = torch.nn.Parameter(
            torch.tensor(float(epsilon), dtype=torch.float64))
        self.sigma = torch.nn.Parameter(
            torch.tensor(float(sigma), dtype=torch.float64))
        self.rc, self.ro = rc, ro

    @property
    def cutoff(self) -> float:
        """``rc``, Å: the calculator's cut-off must reach it."""
        return self.rc

    def forward(self, positions, numbers, cell, edge_index, edge_shift):
        """The energy (eV, scalar tensor); see the class docstring."""
        mask = half_pairs(edge_index, edge_shift)
        r = pair_distances(positions, edge_index, edge_shift, mask)
        s = self.sigma / r
        s2 = s * s
        s6 = s2 * s2 * s2
        t = torch.clamp((r - self.ro) / (self.rc - self.ro), 0.0, 1.0)
        t2 = t * t
        switch = 1 - t2 * t * (10 - 15 * t + 6 * t2)
        return (4 * self.epsilon * (s6 * s6 - s6) * switch).sum()


class PairMLP(torch.nn.Module):
    """A neural pair potential: ``phi(r) = MLP(basis(r)) * fc(r)``.

    ``basis`` is ``n_basis`` Gaussians of width ``cutoff / n_basis`` evenly
    spread over ``[0, cutoff]``, the MLP has smooth activations (so the
    forces are continuously differentiable, which the adjoint needs), and
    ``fc(r) = (1 - (r / cutoff)**2)**3`` takes the pair energy to zero at
    the cut-off with its first and second derivatives.  One species.

    Parameters
    ----------
    cutoff : float
        Å.  Give the calculator the same cut-off (or a larger one).
    n_basis : int
        Radial basis functions.
    hidden : tuple of int
        Widths of the hidden layers.  The defaults make 3,993 parameters.
    energy_scale : float
        eV: the MLP's output is multiplied by it.
    seed : int or None
        Seeds the initial weights (``torch.Generator``), so two models
        made alike are equal.
    activation : {'tanh', 'silu'}
        The hidden layers' activation.  ``tanh``'s derivatives are
        polynomials of its value, which the double-backward pass of the
        adjoint's product reuses: at 512 argon atoms (7 Å, one thread,
        loaded machine) the product took 31.6 ms with tanh against 50.0 ms
        with SiLU, the force call 20.0 against 16.9 ms.
    """

    def __init__(self, cutoff: float = 5.0, n_basis: int = 16,
                 hidden: tuple = (64, 44), energy_scale: float = 0.01,
                 seed: int | None = 0, activation: str = 'tanh'):
        super().__init__()
        cutoff = float(cutoff)
        if not (math.isfinite(cutoff) and cutoff > 0):
            raise ValueError(f'cutoff must be a positive length in Å, got '
                             f'{cutoff!r}')
        activations = {'tanh': torch.nn.Tanh, 'silu': torch.nn.SiLU}
        if activation not in activations:
            raise ValueError(f'activation must be one of '
                             f'{tuple(activations)}, got {activation!r}')
        self.cutoff = cutoff
        self.energy_scale = float(energy_scale)
        self.register_buffer('centres', torch.linspace(
            0.0, cutoff, n_basis, dtype=torch.float64))
        self.width = cutoff / n_basis
        layers, width = [], n_basis
        for h in hidden:
            layers += [torch.nn.Linear(width, h, dtype=torch.float64),
                       activations[activation]()]
            width = h
        layers.append(torch.nn.Linear(width, 1, dtype=torch.float64))
        self.mlp = torch.nn.Sequential(*layers)
        if seed is not None:
            generator = torch.Generator().manual_seed(seed)
            with torch.no_grad():
                for p in self.mlp.parameters():
                    bound = 1 / math.sqrt(p.shape[-1])
                    p.copy_(torch.rand(p.shape, generator=generator,
                                       dtype=torch.float64) * 2 * bound
                            - bound)

    def pair_energy(self, r):
        """``phi(r)`` in eV for a 1-d tensor of distances in Å."""
        z = (r[:, None] - self.centres) / self.width
        phi = self.mlp(torch.exp(-z * z))[:, 0]
        u = r / self.cutoff
        c = 1 - u * u
        return self.energy_scale * phi * (c * c * c)

    def fit_pair_curve(self, target, r_min, points=200, steps=1000,
                       learning_rate=1e-2) -> float:
        """Train the weights so that ``phi(r)`` follows ``target(r)``.

        Parameters
        ----------
        target : callable
            ``target(r)`` in eV for a float64 numpy array of distances in
            Å, e.g. a Lennard-Jones curve.  Beyond the cut-off ``phi`` is
            zero whatever the target; a target that is not near zero
            towards the cut-off cannot be followed there.
        r_min : float
            Å: the fit covers ``[r_min, cutoff]`` (closer pairs should not
            occur in the runs).
        points, steps, learning_rate
            Evenly spaced distances, Adam steps and its learning rate.

        Returns the root-mean-square error over the points after the fit,
        eV.  Deterministic (the same weights from the same start): it runs
        on one torch thread, restored afterwards (two threads took 30 times
        as long on a busy two-core machine).  Fitted to argon's
        Lennard-Jones curve over [3.2, 7] Å with the defaults: 2.4e-4 eV
        RMS against a well depth of 0.0104 eV, in 0.81 s.  Make the
        optimiser for your own training afterwards: this replaces the
        weights in place.
        """
        import numpy as np
        r_np = np.linspace(float(r_min), self.cutoff, int(points))
        device = self.centres.device
        r = torch.from_numpy(r_np).to(device)
        goal = torch.from_numpy(np.asarray(target(r_np),
                                           dtype=np.float64)).to(device)
        optimiser = torch.optim.Adam(self.mlp.parameters(),
                                     lr=learning_rate)
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            for _ in range(int(steps)):
                optimiser.zero_grad()
                loss = ((self.pair_energy(r) - goal) ** 2).mean()
                loss.backward()
                optimiser.step()
            with torch.no_grad():
                error = ((self.pair_energy(r) - goal) ** 2).mean().sqrt()
        finally:
            torch.set_num_threads(threads)
        return float(error)

    def forward(self, positions, numbers, cell, edge_index, edge_shift):
        """The energy (eV, scalar tensor): ``phi`` summed over pairs."""
        mask = half_pairs(edge_index, edge_shift)
        r = pair_distances(positions, edge_index, edge_shift, mask)
        return self.pair_energy(r).sum()
