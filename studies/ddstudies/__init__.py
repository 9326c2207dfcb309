"""ddstudies: the studies of ddsolve, apart from the numerical library.

- :mod:`ddstudies.aggregate`: result files -> one DataFrame / CSV (pandas);
- :mod:`ddstudies.report`: thesis-style tables and plots, the stress study;
- :mod:`ddstudies.bench`: the work-precision benchmark and the contact scaling study.

The Snakemake workflow of the repository (``workflows/``) runs them; ``ddsolve``
itself imports none of pandas, matplotlib or pyamg.
"""
