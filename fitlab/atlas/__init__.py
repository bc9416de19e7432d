"""The layered-model validation atlas (``fitlab atlas``): each layered model family against the
Monte Carlo simulation of its own stack over a grid of its parameters, the region where it is
within 5% named, maps and a page in ``reports/layered_atlas/``, the numbers as package data
(``fitlab/models/data/layered_atlas.json``, data_formats/layered_atlas.md).

- :mod:`fitlab.atlas.grids`: the grids, one entry per model (data);
- :mod:`fitlab.atlas.compute`: the simulation and the model over the simulator's bins, the
  measures;
- :mod:`fitlab.atlas.region`: verdicts, the region in words, the record and
  :func:`~fitlab.atlas.region.within_region` (read by ``fitlab models`` and the fit report);
- :mod:`fitlab.atlas.run`: :func:`atlas`, everything in one call (``fitlab.atlas(...)``).

Names are imported at their first use (PEP 562): ``fitlab models`` reads the region module
without the simulator, JAX or matplotlib.
"""

from fitlab._lazy import exports

_SOURCES = {"atlas": "run", "AtlasResult": "run", "GRIDS": "grids",
            "within_region": "region"}

__all__ = list(_SOURCES)


__getattr__, __dir__ = exports(__name__, _SOURCES)
