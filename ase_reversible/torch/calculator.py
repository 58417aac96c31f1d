"""An ASE calculator for a user's PyTorch energy model, exact and
differentiable.

:class:`TorchCalculator` makes the forces of any float64
``torch.nn.Module`` a pure function of the positions (a canonical
neighbour list, deterministic algorithms, a fixed thread count), so
:class:`~ase_reversible.ReversibleVerlet` runs it out and back bit for
bit; and it offers the differentiable-calculator protocol the reversible
adjoint uses: one double-backward pass per kick gives ``(dF/dx)^T v`` and
``(dF/dθ)^T v`` for every model parameter at once.
"""

from __future__ import annotations

import contextlib
import math
import zlib

import numpy as np
import torch
from ase.calculators.calculator import all_changes

from ..calculators.base import ExactCalculator
from ..core.kernels import (cublas_problem, deterministic_kernels,
                            steady_torchscript)
from .cells import TorchNeighbourList
from .neighbours import NeighbourList


class TorchCalculator(ExactCalculator):
    """ASE calculator for a PyTorch energy model.

    Parameters
    ----------
    model : torch.nn.Module
        ``model(positions [n, 3], numbers [n], cell [3, 3],
        edge_index [2, E], edge_shift [E, 3])`` returns the energy, a
        scalar tensor in eV; positions, cell and shifts in Å, float64;
        numbers and edge_index int64.  Every floating-point parameter and
        buffer must be float64 (call ``model.double()`` before making the
        optimiser).  ``r_ij = x_j - x_i + edge_shift`` for each edge
        ``(i, j)``, both directions of every pair within ``cutoff``,
        sorted (:func:`~ase_reversible.torch.neighbour_list`).
    cutoff : float
        Å: pairs strictly closer are handed to the model.  At least the
        model's own cut-off.
    skin : float
        Å: the neighbour search reaches ``cutoff + skin`` and is repeated
        once an atom has moved more than ``skin / 2``
        (:class:`~ase_reversible.torch.neighbours.NeighbourList`); the
        pairs handed to the model are the same bits whatever the skin.
    device : torch.device or str, optional
        Where the model runs: the device of its parameters and buffers if
        omitted (CPU for a model without any).  A model elsewhere is moved
        there (``model.to(device)``, in place: make the optimiser after,
        as after ``model.double()``).  Inputs go to the device, products
        and parameter gradients are computed there, and energies, forces
        and products come back as float64 numpy arrays.  A device that
        cannot run the model (no CUDA in this torch build, no float64 on
        Apple's MPS, cuBLAS without its deterministic workspace) is
        refused here, before any step.
    threads : int
        Torch threads inside the calculator's calls (the caller's setting
        is restored after each).  The float64 forces of PairMLP and the
        torch LennardJones were the same bits with 1 and 2 threads at 32
        (tests/test_torch.py), 512 and 2048 atoms; fixing the count keeps
        a model whose reductions split by thread count pure.  Two threads
        were much slower than one on a busy two-core machine (its
        benchmark in docs/benchmarks.md).

    Results: ``energy``, ``free_energy`` (eV) and ``forces`` (eV/Å), the
    forces from ``torch.autograd.grad`` of the energy without
    ``create_graph`` (a graph-building pass gave other last bits for MLP
    models, so the run never takes forces from the products).

    ``parameters['weights']`` is a CRC-32 of the bytes of every parameter
    and buffer, with a hash of the modules' plain settings
    (:meth:`weights_fingerprint`), computed whenever ``parameters`` is
    read, so the integrators see any change of the weights (an
    optimiser's step, ``load_state_dict``, an edit through ``.data``) and
    move the anchor of reversal instead of retracing with other forces.
    Cost, measured with 1 thread on a loaded 2-core machine: the CRC
    itself 13 µs for 4,000 float64 parameters, 68 µs for 33,000, 1.9 ms
    for 1,000,000 (SHA-1 took twice as long, BLAKE2b four times); the
    whole fingerprint 48-52 µs for the 3,993 parameters of the default
    :class:`~ase_reversible.torch.PairMLP`, 104 µs for 32,181.  It is
    taken once per force call (so that results cached at unchanged
    positions are not those of other weights) and once per read by the
    integrators' watch (every step when observers are attached): a
    ReversibleVerlet step with an observer took 1.03-1.06 ms against
    0.90-0.93 ms with no fingerprint for Ar13 and that PairMLP (two
    runs), 1.40-1.43 against 1.15-1.16 ms with 32,181 parameters, and
    4.50-5.39 against 4.45-5.06 ms for Ar108 (medians of 9 interleaved
    blocks of 10 steps).  A
    CRC-32 sees every change confined to 32 consecutive bits of the
    weights; a change spread wider goes unseen with probability 2**-32.
    """

    implemented_properties = ['energy', 'free_energy', 'forces']
    #: Deterministic kernels and TorchScript's steady execution are held
    #: around every call here, so force_purity='auto' does not add its
    #: torch handling: off the CPU it probes and spot-checks the forces.
    holds_deterministic_kernels = True
    default_parameters = {'cutoff': None, 'skin': 1.0, 'weights': None}
    parameter_bounds = {'cutoff': 'positive', 'skin': 'non-negative'}
    system_quantities = ('positions', 'numbers', 'cell', 'pbc')
    @property
    def forces_are_pure(self) -> bool:
        """True on the CPU: the neighbour list is a function of positions,
        cell and pbc, sorted, and the model runs with deterministic
        algorithms and a fixed thread count (tested bit for bit after
        moving away and back).  Elsewhere (a GPU) the same holds by
        PyTorch's word for its deterministic kernels, not by a test run
        here, so the integrators probe the forces and spot-check them
        during runs."""
        return self.device.type == 'cpu'

    def __init__(self, model, cutoff, *, skin: float = 1.0, threads: int = 1,
                 device=None, **kwargs):
        if not isinstance(model, torch.nn.Module):
            raise TypeError(f'model must be a torch.nn.Module, got '
                            f'{type(model).__name__}')
        threads = int(threads)
        if threads < 1:
            raise ValueError(f'threads must be a positive integer, got '
                             f'{threads!r}')
        self.device = _runnable_device(model, device)
        # A scripted model (torch.jit.script) gives other bits once
        # TorchScript has optimised it: off for the process, see there.
        steady_torchscript()
        #: Whether pairs are built by :class:`TorchNeighbourList` on the
        #: device (True off the CPU) or by the numpy list (the same bits;
        #: change it, then ``reset()``).
        self.device_neighbours = self.device.type != 'cpu'
        _check_model(model, self.device)
        self.model = model
        self.threads = threads
        self._keep_graph = False
        self._results_weights = None
        super().__init__(cutoff=cutoff, skin=skin, **kwargs)

    # ``parameters`` carries the weights' fingerprint, fresh at every read.
    @property
    def parameters(self):
        """ASE's parameter dict: ``cutoff`` (Å) and ``weights``, the
        fingerprint of the model's weights as they are now (computed at
        each read, see the class docstring for its cost)."""
        params = self._parameters
        if params is not None and getattr(self, 'model', None) is not None:
            params['weights'] = self.weights_fingerprint()
        return params

    @parameters.setter
    def parameters(self, value):
        self._parameters = value

    def set(self, **kwargs):
        """Change ``cutoff`` (Å): checked before anything changes.
        Returns the changed parameters (dict)."""
        if 'weights' in kwargs:
            raise ValueError("'weights' is the model's fingerprint, not a "
                             'setting: change the model (or use '
                             'set_parameter_values).')
        if 'cutoff' in kwargs:
            self._check_cutoff(kwargs['cutoff'])
        return super().set(**kwargs)

    def _forget(self):
        self._lists = None   # (state key, numbers, cell, edges, shifts)
        # The same pairs either way (tests/test_torch_neighbours.py): on
        # the CPU the numpy list, whose skin hits were 1.3-1.6x faster than
        # the torch one's at 32,000 argon atoms here; elsewhere the list is
        # built where the model runs, so no pair crosses to the device.
        cutoff, skin = self._parameters['cutoff'], self._parameters['skin']
        self._neighbours = (TorchNeighbourList(cutoff, skin, self.device)
                            if self.device_neighbours else
                            NeighbourList(cutoff, skin))
        # The last force call's graph (state key, positions tensor, energy,
        # weights' fingerprint), kept once products have been asked for.
        self._graph = None

    def weights_fingerprint(self) -> str:
        """A digest of every parameter's and buffer's bytes and of the
        modules' plain settings, as text: CRC-32 on the CPU, on other
        devices :func:`device_digest` computed where the tensors are.

        Settings are the public attributes of each submodule that are
        numbers, strings, booleans (``training``) or tuples of them, such
        as :class:`~ase_reversible.torch.PairMLP`'s ``energy_scale``.
        Other Python state of a model (a dict, an array attribute) is not
        seen: attach a new calculator after changing it.
        """
        if self.device.type == 'cpu':
            crc = 0
            for tensor in self._tensors():
                crc = zlib.crc32(_as_bytes(tensor), crc)
            digest = f'crc32:{crc:08x}'
        else:
            digest = device_digest(list(self._tensors()))
        # Python's hash of the settings: equal settings, equal hashes
        # within the process, which is where the fingerprints are compared.
        settings = hash(tuple(
            (k, v) for module in self.model.modules()
            for k, v in vars(module).items()
            if k[0] != '_' and _is_plain(v)))
        return f'{digest}:{settings & 0xFFFFFFFFFFFFFFFF:016x}'

    def _tensors(self):
        for _, p in self.model.named_parameters():
            yield p
        for _, b in self.model.named_buffers():
            yield b

    # -- the differentiable-calculator protocol ---------------------------

    @property
    def differentiable_parameters(self):
        """Names of ``model.named_parameters()`` that require grad."""
        return tuple(name for name, p in self.model.named_parameters()
                     if p.requires_grad)

    def parameter_values(self, names=None) -> dict:
        """``{name: value}`` copies: float64 arrays, or floats for scalar
        parameters; all differentiable parameters if ``names`` is None."""
        params = self._named(names)
        return {name: _to_value(p) for name, p in params.items()}

    def set_parameter_values(self, values: dict):
        """Write ``{name: array-like}`` into the model's parameters.

        Shapes must match and values be finite (ValueError otherwise,
        nothing written).  The weights' fingerprint changes, so the
        integrators move their anchor at their next step.
        """
        params, arrays = self._checked_arrays(values, 'value')
        with torch.no_grad():
            for name, array in arrays.items():
                params[name].copy_(torch.from_numpy(array))
        self.reset()

    def assign_gradients(self, gradients: dict):
        """Put ``{name: dL/dθ}`` (``Gradients.parameters`` from
        ``backpropagate``) into each parameter's ``.grad``, as a torch
        optimiser expects after ``loss.backward()``; parameters not named
        keep theirs.  Shapes must match and values be finite (ValueError,
        nothing written)."""
        params, arrays = self._checked_arrays(gradients, 'gradient')
        for name, array in arrays.items():
            p = params[name]
            p.grad = torch.from_numpy(array.copy()).to(device=p.device,
                                                        dtype=p.dtype)

    def _checked_arrays(self, values, what):
        """``(parameters by name, float64 arrays by name)`` for ``values``,
        every one checked before anything is written."""
        params = self._named(list(values))
        arrays = {}
        for name, value in values.items():
            array = np.asarray(value, dtype=np.float64)
            shape = tuple(params[name].shape)
            if array.shape != shape:
                raise ValueError(f'The {what} of {name} must have shape '
                                 f'{shape}, got {array.shape}')
            if not np.isfinite(array).all():
                raise ValueError(f'The {what} of {name} holds NaN or '
                                 'infinite values.')
            arrays[name] = array
        return params, arrays

    def vector_jacobian_product(self, atoms, v_nc, parameters=()):
        """``((dF/dx)^T v, {name: (dF/dθ)^T v})`` at the atoms' positions.

        One double-backward pass: the energy's gradient with a graph,
        then one backward of ``grad · v`` to the positions and every named
        parameter.  ``v_nc`` is ``[n_atoms, 3]``; ``dx_nc`` is
        ``[n_atoms, 3]`` in eV/Å² x (unit of ``v``) (``-H v``, ``H`` the
        Hessian); each ``dtheta`` value is shaped like the parameter
        (a float for a scalar one).  Leaves the atoms and the results of
        the ordinary force call untouched.
        """
        v_nc = self.as_vector(atoms, v_nc)
        names = tuple(parameters)
        params = self._named(names)
        # From now on the force calls keep their graph: the adjoint asks
        # for the product where it has just asked for the forces.
        self._keep_graph = True
        graph, self._graph = self._graph, None
        with self._scope():
            if graph is not None and graph[0] == self._state_key(atoms) \
                    and graph[3] == self.weights_fingerprint():
                x, energy = graph[1], graph[2]
            else:
                x, numbers, cell, edge_index, edge_shift = \
                    self._inputs(atoms)
                x.requires_grad_(True)
                energy = self.model(x, numbers, cell, edge_index,
                                    edge_shift)
            g = _gradient(energy, x, create_graph=True)
            inputs = [x] + [params[name] for name in names]
            grads = _products(g, torch.from_numpy(v_nc).to(self.device),
                              inputs)
        dx_nc = _negated(grads[0], x)
        dtheta = {}
        for name, grad in zip(names, grads[1:]):
            value = _negated(grad, params[name])
            dtheta[name] = float(value) if value.ndim == 0 else value
        return dx_nc, dtheta

    def _force_parameter_derivative(self, atoms, name):
        """``dF/d(name)`` ``[n_atoms, 3]`` for a scalar parameter (eV/Å per
        unit of it), by a product taken twice; a tensor parameter has one
        such array per entry: use :meth:`vector_jacobian_product`."""
        (param,) = self._named([name]).values()
        if param.numel() != 1:
            raise ValueError(
                f'{name} has {param.numel()} entries: dF/d{name} would be '
                'one [n_atoms, 3] array per entry; use '
                'vector_jacobian_product for its product with a vector.')
        with self._scope():
            x, numbers, cell, edge_index, edge_shift = self._inputs(atoms)
            x.requires_grad_(True)
            energy = self.model(x, numbers, cell, edge_index, edge_shift)
            g = _gradient(energy, x, create_graph=True)
            dg = None
            if g is not None and g.requires_grad:
                # u . dg/dθ is linear in u: its gradient in u is dg/dθ.
                u = torch.zeros_like(g, requires_grad=True)
                (ug,) = torch.autograd.grad(g, param, grad_outputs=u,
                                            create_graph=True,
                                            allow_unused=True)
                if ug is not None:
                    (dg,) = torch.autograd.grad(ug.sum(), u,
                                                allow_unused=True)
        return _negated(dg, x)

    def hessian_vector_product(self, atoms, v_nc):
        """``H v`` (eV/Å² x unit of ``v``): minus the position part of
        :meth:`vector_jacobian_product`, for the adjoint's ``hvp``."""
        dx_nc, _ = self.vector_jacobian_product(atoms, v_nc)
        return -dx_nc

    # -- ASE calculator interface ---------------------------------------

    def check_state(self, atoms, tol=1e-15):
        """What changed since the last calculation: the atoms compared bit
        for bit, and ``'weights'`` if the model changed in place."""
        changes = super().check_state(atoms, tol)
        if (not changes and self._results_weights is not None
                and self._results_weights != self.weights_fingerprint()):
            changes = ['weights']
        return changes

    def calculate(self, atoms=None, properties=('energy',),
                  system_changes=all_changes):
        """ASE's hook: ``energy``, ``free_energy`` (eV), ``forces``
        (eV/Å) into ``results``."""
        super().calculate(atoms, properties, system_changes)
        _check_model(self.model, self.device)
        self._check_cutoff(self._cutoff())   # the model's may have grown
        with self._scope():
            x, numbers, cell, edge_index, edge_shift = \
                self._inputs(self.atoms)
            x.requires_grad_(True)
            energy = self.model(x, numbers, cell, edge_index, edge_shift)
            _check_energy(energy)
            # Keeping the graph changes no bit of the gradient.
            g = _gradient(energy, x, retain_graph=self._keep_graph)
        f_nc = _negated(g, x)
        self._results_weights = self.weights_fingerprint()
        self._graph = ((self._state_key(self.atoms), x, energy,
                        self._results_weights) if self._keep_graph
                       else None)
        value = float(energy.detach())
        self.results['energy'] = self.results['free_energy'] = value
        self.results['forces'] = f_nc

    # -- plumbing ---------------------------------------------------------

    def _named(self, names):
        params = {name: p for name, p in self.model.named_parameters()
                  if p.requires_grad}
        if names is None:
            return params
        if isinstance(names, str):
            names = [names]
        unknown = [n for n in names if n not in params]
        if unknown:
            raise ValueError(f'No parameter {unknown[0]!r} to differentiate; '
                             f'available: {tuple(params)}')
        return {name: params[name] for name in names}

    @contextlib.contextmanager
    def _scope(self):
        """Deterministic algorithms and the calculator's thread count,
        the caller's settings restored afterwards; a model operation
        without a deterministic kernel on this device is refused with
        what to do."""
        threads = torch.get_num_threads()
        if threads != self.threads:
            torch.set_num_threads(self.threads)
        try:
            with deterministic_kernels(), torch.enable_grad():
                yield
        except RuntimeError as error:
            if 'deterministic' not in str(error):
                raise
            raise RuntimeError(
                f'The model uses an operation without a deterministic '
                f'kernel on {self.device}, so its forces could differ at the '
                'same positions and the run could not be reversed. Replace '
                'that operation (an index_add_ or scatter_add_ in place of '
                'an index_put_ or a histogram, say), or run the model on '
                f'another device. PyTorch said: {error}') from error
        finally:
            if threads != self.threads:
                torch.set_num_threads(threads)

    def _state_key(self, atoms):
        return (atoms.positions.tobytes(), atoms.cell.array.tobytes(),
                atoms.pbc.tobytes(), atoms.arrays['numbers'].tobytes(),
                self._cutoff())

    def _inputs(self, atoms):
        """Fresh position tensor and the cached list for these positions."""
        device = self.device
        x = torch.from_numpy(np.array(atoms.positions,
                                      dtype=np.float64)).to(device)
        key = self._state_key(atoms)
        lists = self._lists
        if lists is None or lists[0] != key:
            edge_index, edge_shift, _ = self._neighbours(
                x if self.device_neighbours else atoms.positions,
                atoms.cell.array, atoms.pbc)
            lists = (key, torch.from_numpy(
                         atoms.arrays['numbers'].astype(np.int64)).to(device),
                     torch.from_numpy(atoms.cell.array.copy()).to(device),
                     torch.as_tensor(edge_index, device=device),
                     torch.as_tensor(edge_shift, device=device))
            self._lists = lists
        return (x,) + lists[1:]

    def _cutoff(self) -> float:
        return self._parameters['cutoff']

    def _check_relations(self):
        self._check_cutoff(self._parameters['cutoff'])

    def _check_cutoff(self, cutoff):
        if cutoff is None:
            raise ValueError('TorchCalculator needs a cutoff (Å): the '
                             'neighbour list hands the model the pairs '
                             'strictly inside it.')
        try:
            cutoff = float(cutoff)
        except (TypeError, ValueError):
            raise TypeError(f'cutoff must be a number (Å), got {cutoff!r}') \
                from None
        if not (math.isfinite(cutoff) and cutoff > 0):
            raise ValueError(f'cutoff must be a finite, positive length in '
                             f'Å, got {cutoff!r}')
        model_cutoff = getattr(self.model, 'cutoff', None)
        if isinstance(model_cutoff, (int, float)) and model_cutoff > cutoff:
            raise ValueError(
                f"The model's cutoff {model_cutoff} Å is beyond the "
                f"calculator's {cutoff} Å: pairs in between would be "
                "missing. Give the calculator at least the model's cutoff.")


def _runnable_device(model, device):
    """The ``torch.device`` the model runs on: ``device``, the model moved
    there if it is elsewhere, or the device of its tensors; refused, with
    what to do, where the model cannot run."""
    tensors = list(model.parameters()) + list(model.buffers())
    if device is None:
        devices = sorted({str(t.device) for t in tensors})
        if len(devices) > 1:
            raise ValueError(
                f"The model's tensors are on several devices {devices}: "
                "move it to one (model.to('cuda'), say) or give device=.")
        device = torch.device(devices[0] if devices else 'cpu')
    else:
        try:
            device = torch.device(device)
        except (RuntimeError, TypeError) as error:
            raise ValueError(f'device={device!r} is not a torch device: '
                             f'{error}') from None
    if device.type == 'cuda' and not torch.cuda.is_available():
        raise RuntimeError(
            f'device={str(device)!r}, but this torch ({torch.__version__}) '
            'finds no CUDA device: install a CUDA build of torch on a machine '
            "with an NVIDIA GPU, or use device='cpu'.")
    if device.type == 'mps':
        raise RuntimeError(
            "Apple's MPS has no float64, and TorchCalculator computes in "
            "float64 only (float32 forces are too coarse for exact reversal "
            "and the adjoint): use device='cpu'.")
    problem = cublas_problem(device)
    if problem is not None:
        raise RuntimeError(problem)
    if any(t.device != device for t in tensors):
        try:
            model.to(device)
        except (RuntimeError, AssertionError) as error:
            raise RuntimeError(f'The model could not be moved to {device}: '
                               f'{error}') from error
    return device


def _check_model(model, device):
    """Refuse a model with tensors that are not float64 or not on
    ``device`` (checked at every call: a model can be changed after the
    calculator was made)."""
    for name, t in list(model.named_parameters()) + list(
            model.named_buffers()):
        if t.device != device:
            raise RuntimeError(
                f'{name} is on {t.device}, but the calculator computes on '
                f'{device}: move the model back (model.to({str(device)!r})) '
                'or make a calculator for the new device.')
        if t.is_floating_point() and t.dtype != torch.float64:
            raise TypeError(
                f'TorchCalculator computes in float64 only, but {name} is '
                f'{t.dtype}: call model.double() (before making the '
                'optimiser, which keeps references to the old tensors). '
                'In float32 the forces are too coarse for exact reversal '
                'and the adjoint, and 2-thread float32 runs gave other bits '
                'in 9 of 40 trials here.')


def _check_energy(energy):
    if not isinstance(energy, torch.Tensor) or energy.numel() != 1:
        raise TypeError('The model must return the energy as a scalar '
                        f'tensor (eV), got {type(energy).__name__}'
                        + (f' of shape {tuple(energy.shape)}'
                           if isinstance(energy, torch.Tensor) else ''))
    if energy.dtype != torch.float64:
        raise TypeError(f'The model returned a {energy.dtype} energy: '
                        'compute in float64 (model.double()).')


def _gradient(energy, x, **kwargs):
    """``dE/dx``, or None (zero) where the energy does not depend on the
    positions (no pair within the cut-off, for a model that then returns
    a constant)."""
    if not energy.requires_grad:
        return None
    (g,) = torch.autograd.grad(energy, x, allow_unused=True, **kwargs)
    return g


def _products(g, v, inputs):
    """Gradients of ``g . v`` with respect to ``inputs`` (None where zero)."""
    if g is None or not g.requires_grad:
        return [None] * len(inputs)
    return list(torch.autograd.grad((g * v).sum(), inputs,
                                    allow_unused=True))


def _negated(grad, like):
    """``-grad`` as a float64 numpy array (zeros for an unused input)."""
    if grad is None:
        return np.zeros(tuple(like.shape))
    return (-grad.detach()).cpu().numpy().astype(np.float64, copy=True)


def _to_value(p):
    array = p.detach().cpu().numpy().astype(np.float64, copy=True)
    return float(array) if array.ndim == 0 else array


def _is_plain(value):
    if isinstance(value, tuple):
        return all(map(_is_plain, value))
    return value is None or isinstance(value, (bool, int, float, str))


def _as_bytes(tensor):
    t = tensor.detach()
    if not t.is_contiguous():
        t = t.contiguous()
    return t.numpy().data.cast('B') if t.numel() else b''


#: Two primes below 2**31: a weighted sum of 32-bit words modulo each stays
#: exact in int64 (word < 2**32, weight < 2**31, so each term, reduced,
#: is < 2**31, and 2**32 of them sum below 2**63).
_DIGEST_PRIMES = (2**31 - 1, 2**31 - 19)


def device_digest(tensors) -> str:
    """A digest of the tensors' bytes computed on their device: for each
    of two primes ``p``, ``sum_k w_k * (word_k mod p) mod p`` over the
    32-bit words of all the tensors, with weights ``w_k = (k a + b) mod
    p`` fixed per position, so a change of one word changes both sums
    and a change spread over many goes unseen with a chance near 2**-62.

    Integer sums are exact, so the digest is the same whatever order the
    device adds in; it costs a dozen kernels and one transfer of two
    numbers, against the copy of every weight to the host that a CRC
    would need.
    """
    if not tensors:
        return 'mod:0'
    device = tensors[0].device
    flat = torch.cat([t.detach().contiguous().reshape(-1).view(torch.uint8)
                      for t in tensors])
    pad = (-flat.numel()) % 4
    if pad:
        flat = torch.cat([flat, flat.new_zeros(pad)])
    words = flat.view(torch.int32).to(torch.int64) & 0xFFFFFFFF
    k = torch.arange(words.numel(), dtype=torch.int64, device=device)
    sums = []
    for p, a, b in zip(_DIGEST_PRIMES, (40503, 69069), (1, 12345)):
        w = (k * a + b) % p
        sums.append((((words % p) * w) % p).sum() % p)
    s0, s1 = torch.stack(sums).tolist()
    return f'mod:{words.numel():x}:{s0:08x}{s1:08x}'
