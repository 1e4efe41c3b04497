"""The paper's results, one module per figure or table, run by ``iap-mjx reproduce <figure>``:
each trains into resumable run directories (:mod:`iap_mjx.paper.report_runs`; ``fig10`` draws runs
trained elsewhere), writes its figure's PNG (and JSON, but ``fig10``) and, given ``--results``,
its RESULTS.md section (``fig1_fig6``: PNG and JSON only):

- :mod:`~iap_mjx.paper.fig1_fig6`: inference time per forward pass next to return (Figures 1, 6);
- :mod:`~iap_mjx.paper.fig7`: the attention's shape on the Distracting Control Suite;
- :mod:`~iap_mjx.paper.fig8`: training curves against wall-clock time, brute force against IAP;
- :mod:`~iap_mjx.paper.table1`: the Distracting Control Suite, and generalisation beyond it;
- :mod:`~iap_mjx.paper.fig10`, :mod:`~iap_mjx.paper.fig11`, :mod:`~iap_mjx.paper.table2`: the
  quadruped's course: what its IAP high level selects, IAP against a CNN and a blind policy,
  and the patch size and stride;
- :mod:`~iap_mjx.paper.gates`: beyond the paper, the quadruped's gates corridor seen through
  depth, IAP against the blind control;
- :mod:`~iap_mjx.paper.courses`: the course reports' rows, summaries, eyes-closed table and figure;
- :mod:`~iap_mjx.paper.evaluations`: evaluations of a checkpoint kept beside it.
"""
