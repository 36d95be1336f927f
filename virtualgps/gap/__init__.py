"""Sim-to-real gap diagnosis (DESIGN section 7): real runs in, located gaps, fitted effects and a
calibrated profile out.

Modules, in the order data flows: :mod:`.ingest` (real logs and their truth), :mod:`.runs`
(each run aligned with the simulator), :mod:`.ensemble` (re-simulating a run as an ensemble of
seeds), :mod:`.metrics` and :mod:`.where` (statistics per segment), :mod:`.bands` (a real
value against its seeds: calibrated bands and the score), :mod:`.causes` (differences that are
not receiver effects), :mod:`.design` (held-out units and the outer test), :mod:`.effects`
(candidate effects and their grids), :mod:`.simulator` and :mod:`.jobs` (batched, cached
ensembles on local or Dask workers), :mod:`.select` (choosing effects), :mod:`.diagnose` (the
nested choice and the located gaps), :mod:`.tool` (the whole diagnosis and its report),
:mod:`.selfcheck` and :mod:`.selfcheck_real` (withheld-effect trials). The profile calibration
on the shared MTK logs is a client of the same pieces in ``tools/`` (it carries what was fitted
on those logs; nothing here does).
"""
