"""PyTorch models: the product against a force call, and the neighbour
list against ASE's.

Measured by benchmarks/torch_products.py, whose docstring gives the method.
"""

from __future__ import annotations

from . import markdown_table

TITLE = 'PyTorch models: products and neighbour lists'


def plot(results, figures):
    """No plot: tables."""


def markdown(results):
    if 'skipped' in results:
        return f"Not measured: {results['skipped']}."
    cases = results['cases']
    rounds = cases[0]['rounds']
    rows = [[c['model'], c['n_atoms'], c['threads'], c['n_edges'],
             f"{c['force_cpu'] * 1e3:.3g}", f"{c['product_cpu'] * 1e3:.3g}",
             f"{c['product_ratio_cpu']:.2f}",
             f"{c['product_fresh_ratio_cpu']:.2f}",
             f"{c['product_ratio_wall']:.2f}"] for c in cases]
    nl = [[c['model'], c['n_atoms'], f"{c['cutoff']:g}", c['n_edges'],
           f"{c['neighbours_cpu'] * 1e3:.3g}",
           f"{c['neighbours_skin_cpu'] * 1e3:.3g}",
           f"{c['ase_neighbours_cpu'] * 1e3:.3g}",
           f"{c['ase_over_ours_cpu']:.1f}"]
          for c in cases if 'neighbours_cpu' in c]
    load = results.get('load_average')
    return (
        '`TorchCalculator` (docs/torch.md) with the pair MLP (3,993 '
        'parameters, cut-off 7 Å) and the torch Lennard-Jones (cut-off '
        '10.2 Å), periodic fcc argon, PyTorch '
        f"{results['torch']}, float64, median of {rounds} interleaved "
        'rounds'
        + (f' (one-minute load average {load[0]:.1f} at the start, '
           f'{load[1]:.1f} at the end, on a machine shared with other work: '
           'the ratios, taken within each round, are the result)'
           if load else '') + '. '
        'A force call selects the pairs from the candidates its neighbour '
        'list kept (1 Å skin); the product is '
        '`vector_jacobian_product` for the positions and every parameter '
        'at once, from the graph the force call kept, and "fresh" the same '
        'product running its own forward pass. Times are CPU time of all '
        'threads; the last column is the ratio of wall times. With 2 '
        'threads on a machine whose cores are busy with other work, '
        "torch's worker threads wait for a core at every parallel region: "
        'those rows measure that wait as much as the work.\n\n'
        + markdown_table(['model', 'atoms', 'threads', 'edges',
                          'force call (ms CPU)', 'product (ms CPU)',
                          'product / force', 'fresh / force',
                          'product / force (wall)'], rows)
        + '\n\n**Neighbour list** (one thread): '
        '`ase_reversible.torch.neighbour_list` searching from scratch, '
        '`NeighbourList` selecting from candidates kept within its 1 Å '
        "skin (the same bits), and ASE's `neighbor_list('ijS', ...)` at "
        'the same cut-off, CPU time.\n\n'
        + markdown_table(['model', 'atoms', 'cut-off (Å)', 'edges',
                          'search (ms)', 'with skin (ms)', "ASE's (ms)",
                          'ASE / search'], nl))
