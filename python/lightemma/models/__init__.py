"""The models lightemma knows: the catalog, prices, token rules, name matching and the paper's tables.

* :mod:`lightemma.models.catalog` — the paper's 15 models and the baselines
  (:class:`~lightemma.models.catalog.ModelInfo`), lookup and resolution of any model string;
* :mod:`lightemma.models.prices` — interactive and batch prices per model, with their sources;
* :mod:`lightemma.models.tokens` — published image-token rules and typical output tokens, for estimates;
* :mod:`lightemma.models.names` — a run's model string matched to a paper model, its family, its paper row;
* :mod:`lightemma.models.paper` — the paper's Tables I and II as data (a leaf: it imports nothing of lightemma).

This file imports nothing, so that importing one of them does not import the others.
"""
