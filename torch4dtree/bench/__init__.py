"""The timing benchmarks behind ``torch4dtree benchmark`` (and the scripts in ``benchmarks/``), each a function
returning a JSON-ready dict: :mod:`.curves` (curve registration vs fdasrsf), :mod:`.trees` (3D tree registration on
Pheno4D vs the paper), :mod:`.fourd` and :mod:`.temporal` (the 4D half), :mod:`.model` (the generative model),
:mod:`.hierarchy` (hierarchy rules and identity accuracy) and :mod:`.all` (everything, with ratios).

Built on :mod:`torch4dtree.evaluate` (its summary statistics, the paper's timings, the machine record, the oracle
layout); ``evaluate`` never imports ``bench``, and neither imports the command line.
"""
