"""Sim-to-real gap diagnosis (DESIGN section 7): real runs in, located gaps, fitted effects and a
calibrated profile out.

Modules: :mod:`.ingest` (real logs and their truth), :mod:`.metrics` (statistics of any run of
epochs), :mod:`.ensemble` (re-simulating a run as an ensemble of seeds), :mod:`.where` (metrics
per segment against the ensemble's band), :mod:`.effects` (candidate effects, fits on training
data, held-out gap), :mod:`.diagnose` (the whole diagnosis), :mod:`.selfcheck` (withheld-effect
trials); :mod:`.reallogs` and :mod:`.calibration` are the profile calibration on the shared MTK
logs, one client of the same pieces.
"""
