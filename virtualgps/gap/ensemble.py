"""Re-simulating a real run as an ensemble of seeds: the same receiver core, at the real epochs,
along the run's truth, from the run's own power-on.

A :class:`RunSetup` is everything the simulator needs of one run, small and picklable, so an
ensemble job (:class:`EnsembleJob`: a run, a profile and some seeds) can go to a local worker
process or a Dask worker. Workers load the scene and the TLE set once (by path) and keep each
run's sky (satellites, rays, reflections: what does not depend on the random numbers) between
jobs, so fitting an effect's parameters over a grid costs only the random part of the receiver
(:func:`virtualgps.receiver.core.simulate` with ``sky=``). Every seed is its own generator, so an
ensemble's result does not depend on how its seeds are split into jobs or where they run.
"""

from __future__ import annotations

import hashlib
import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from virtualgps.receiver.core import simulate
from virtualgps.receiver.definition import Georef, Receiver
from virtualgps.receiver.params import (
    ConstellationsParams,
    FoliageParams,
    NlosParams,
    Profile,
    SkyParams,
)
from virtualgps.receiver.skyview import Sky, compute_sky
from virtualgps.receiver.state import initial_state, running_state

# A worker keeps at most this many skies (one per run and sky-relevant profile settings).
SKY_CACHE_SIZE = 48


@dataclass(frozen=True)
class RunSetup:
    """One real run, as the simulator replays it (``n`` real epochs).

    key : unique name of the run
    t_unix_s : (n,) float, the real log's epoch times, UTC seconds
    antenna_enu_m : (n, 3) float, metres, the truth in the scene frame of ``georef`` (0 where
        not posed)
    vel_enu_mps : (n, 3) float, m/s, ENU (NaN where unknown)
    valid : (n,) bool, the truth is known at the epoch (only these epochs are compared)
    power_on_unix_s : when the real receiver was switched on (its log's first epoch), UTC s;
        NaN: the log starts with a fix (the receiver was already running: no start-up)
    georef : the scene origin
    scene_path : the scene folder (None: open sky)
    tle_path : the ephemeris file, or TLE sets joined by ``os.pathsep`` (:func:`ephemeris_of`)
    sky_shift_s : seconds subtracted before propagating the satellites (0: the true sky)
    digest : identifies the run's epochs and positions (what a worker's sky cache is keyed by)
    systems : RINEX letters of the systems whose satellites are compared (the columns of the
        run's view: those the profile under test tracks and those a ``constellations``
        candidate may add); a profile tracking fewer leaves the others' columns empty
    posed : (n,) bool, the epochs the simulated receiver has a position at: ``valid`` and
        short gaps in the truth, bridged (``virtualgps.gap.runs.SIM_MAX_GAP_S``); None:
        ``valid``
    """

    key: str
    t_unix_s: np.ndarray
    antenna_enu_m: np.ndarray
    vel_enu_mps: np.ndarray
    valid: np.ndarray
    power_on_unix_s: float
    georef: Georef
    scene_path: str | None
    tle_path: str
    sky_shift_s: float = 0.0
    digest: str = ""
    systems: str = "G"
    posed: np.ndarray | None = None

    @property
    def pose_valid(self) -> np.ndarray:
        """(n,) bool, the epochs the simulated receiver has a position at."""
        return self.valid if self.posed is None else self.posed


def setup_digest(t_unix_s: np.ndarray, antenna_enu_m: np.ndarray, valid: np.ndarray,
                 *context: object) -> str:
    """A short hash of a run's epochs, positions and context (scene, TLE, georeference)."""
    h = hashlib.blake2b(digest_size=12)
    for a in (t_unix_s, antenna_enu_m, valid):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr(context).encode())
    return h.hexdigest()


@dataclass(frozen=True)
class EnsembleJob:
    """Simulate one run with one profile for some seeds."""

    setup: RunSetup
    profile: Profile
    seeds: tuple[int, ...]


@dataclass(frozen=True)
class Ensemble:
    """Simulated output of one run over ``s`` seeds, ``n`` epochs, ``k`` satellites.

    seeds : (s,) int
    lat_deg, lon_deg, alt_hae_m : (s, n) float, the fixes (NaN without a fix)
    quality : (s, n) int8, GGA quality
    hdop : (s, n) float32
    speed_mps : (s, n) float32, reported speed (NaN without a fix)
    used : (s, n, k) bool
    cn0_dbhz : (s, n, k) float32, NaN where not tracked
    """

    seeds: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_hae_m: np.ndarray
    quality: np.ndarray
    hdop: np.ndarray
    speed_mps: np.ndarray
    used: np.ndarray
    cn0_dbhz: np.ndarray

    @staticmethod
    def concat(parts: list[Ensemble]) -> Ensemble:
        """Join ensembles of the same run along the seed axis."""
        if len(parts) == 1:
            return parts[0]
        return Ensemble(**{
            name: np.concatenate([getattr(p, name) for p in parts])
            for name in Ensemble.__dataclass_fields__
        })


@dataclass(frozen=True)
class Geometry:
    """What the scene and the sky are at each epoch of a run (no receiver): ``n`` epochs,
    ``k`` satellites.

    prn : (k,) int; az_deg, el_deg : (n, k) float32, degrees
    crosses_building : (n, k) bool, the direct path hits an occluder of the scene
    """

    prn: np.ndarray
    az_deg: np.ndarray
    el_deg: np.ndarray
    crosses_building: np.ndarray


_SCENES: dict[str | None, object] = {}
_EPHEMERIDES: dict[tuple[str, str | None], object] = {}
_SKIES: OrderedDict[tuple, Sky] = OrderedDict()


def _scene(path: str | None):
    if path is None:
        return None
    if path not in _SCENES:
        from virtualgps.sky.scene import load_scene

        _SCENES[path] = load_scene(path)
    return _SCENES[path]


def ephemeris_of(tle: str, letters: str | None):
    """The ephemeris of a diagnosis, loaded once per process: ``tle`` is one file (TLE set,
    RINEX navigation file, lookup table) or several TLE sets joined by ``os.pathsep`` (one per
    system's group); its satellites of the systems ``letters`` (RINEX letters; None: all)."""
    if (tle, letters) not in _EPHEMERIDES:
        from virtualgps.sky import ephemeris as eph

        paths = tle.split(os.pathsep)
        _EPHEMERIDES[tle, letters] = (
            eph.load_ephemeris_file(Path(paths[0]), letters) if len(paths) == 1
            else eph.load_tle_sets(paths, systems_kept=letters))
    return _EPHEMERIDES[tle, letters]


def receiver_for(setup: RunSetup, profile: Profile) -> Receiver:
    """The receiver of a run (scene and ephemeris loaded once per process; the ephemeris's
    satellites of the systems the profile tracks)."""
    scene = _scene(setup.scene_path)  # (its own georeference is the setup's)
    return Receiver(profile, ephemeris_of(setup.tle_path, profile.constellations.letters()),
                    scene, setup.georef, setup.sky_shift_s)


def _sky_key(setup: RunSetup, profile: Profile) -> tuple:
    """The profile settings :func:`virtualgps.receiver.skyview.compute_sky` depends on."""
    mp = profile.multipath
    # (georef: the antenna's geodetic position, hence every direction, follows the conversion)
    return (setup.digest or id(setup), profile.georef, repr(profile.sky),
            repr(profile.foliage), repr(profile.sky_mask), repr(profile.nlos), mp.enabled,
            mp.max_dist_m, profile.constellations.letters())


def _antenna(setup: RunSetup) -> np.ndarray:
    return np.where(setup.pose_valid[:, None], setup.antenna_enu_m, 0.0)


def run_sky(rx: Receiver, setup: RunSetup) -> Sky:
    """The run's sky under the receiver's profile, cached per process."""
    key = _sky_key(setup, rx.profile)
    sky = _SKIES.get(key)
    if sky is None:
        sky = compute_sky(rx, setup.t_unix_s, _antenna(setup))
        _SKIES[key] = sky
        while len(_SKIES) > SKY_CACHE_SIZE:
            _SKIES.popitem(last=False)
    else:
        _SKIES.move_to_end(key)
    return sky


def simulate_job(job: EnsembleJob) -> Ensemble:
    """Run the receiver over a run's epochs once per seed (the unit of work of an ensemble).

    Each seed runs the receiver with ``numpy.random.default_rng(seed)`` over every real epoch
    in one batch, as replay does, after a start at the run's power-on drawn from
    ``default_rng([seed, 1])``.

    Parameters
    ----------
    job : the run, the profile and the seeds

    Returns
    -------
    ensemble : the seeds' outputs
    """
    from virtualgps.receiver.errors import prefer_lfilter

    prefer_lfilter()  # an ensemble simulates millions of epochs
    setup, prof = job.setup, job.profile
    rx = receiver_for(setup, prof)
    sky = run_sky(rx, setup)
    ant = _antenna(setup)
    vel = np.where(setup.pose_valid[:, None], np.nan_to_num(setup.vel_enu_mps), 0.0)
    n_sat = len(rx.ephemeris.prn)
    cols = _view_columns(setup, rx)
    out: dict[str, list[np.ndarray]] = {k: [] for k in Ensemble.__dataclass_fields__}
    for seed in job.seeds:
        rng = np.random.default_rng(seed)
        # The start draws from a generator of its own: every kind of start leaves the epochs'
        # random numbers alike (common random numbers across a cold_start fit's grid).
        start_rng = np.random.default_rng([seed, 1])
        state = (initial_state(prof, setup.power_on_unix_s, start_rng, n_sat)
                 if np.isfinite(setup.power_on_unix_s) else running_state(prof, n_sat))
        fixes, _ = simulate(rx, setup.t_unix_s, ant, vel, setup.pose_valid, state, rng,
                            sky=sky)
        out["seeds"].append(np.array([seed]))
        out["lat_deg"].append(fixes.lat_deg)
        out["lon_deg"].append(fixes.lon_deg)
        out["alt_hae_m"].append(fixes.alt_msl_m + fixes.geoid_sep_m)
        out["quality"].append(fixes.quality)
        out["hdop"].append(fixes.hdop.astype(np.float32))
        out["speed_mps"].append(fixes.speed_mps.astype(np.float32))
        cn0 = np.where(fixes.in_view, fixes.cn0_dbhz, np.nan).astype(np.float32)
        used = fixes.used
        if cols is not None:  # (into the view's columns: systems not tracked stay empty)
            used = np.zeros((used.shape[0], cols[1]), bool)
            used[:, cols[0]] = fixes.used
            cn0 = np.full(used.shape, np.nan, np.float32)
            cn0[:, cols[0]] = np.where(fixes.in_view, fixes.cn0_dbhz, np.nan)
        out["used"].append(used)
        out["cn0_dbhz"].append(cn0)
    return Ensemble(
        seeds=np.concatenate(out["seeds"]),
        **{k: np.stack(v) for k, v in out.items() if k != "seeds"},
    )


def _view_columns(setup: RunSetup, rx: Receiver) -> tuple[np.ndarray, int] | None:
    """Where the receiver's satellites sit among the view's (``setup.systems``), and how many
    the view has; None when they are the same."""
    letters = rx.profile.constellations.letters()
    if letters == setup.systems:
        return None
    view = [int(p) for p in ephemeris_of(setup.tle_path, setup.systems).prn]
    at = {p: k for k, p in enumerate(view)}
    return np.array([at[int(p)] for p in rx.ephemeris.prn], dtype=np.int64), len(view)


def geometry_job(setup: RunSetup) -> Geometry:
    """Satellite directions and which direct paths cross a building, along a run.

    A bare receiver (no effects; foliage neither blocks nor attenuates) gives the geometry, so
    it is the same whatever profile is under test.
    """
    from virtualgps.sky import systems as sy

    prof = Profile(name="geometry", sky=SkyParams(elevation_mask_deg=0.0, foliage="ignore"),
                   foliage=FoliageParams(enabled=False), nlos=NlosParams(enabled=False),
                   constellations=ConstellationsParams(
                       enabled=True, systems=tuple(sy.system_named(x).name
                                                   for x in setup.systems)))
    rx = receiver_for(setup, prof)
    sky = compute_sky(rx, setup.t_unix_s, _antenna(setup))
    return Geometry(
        prn=np.asarray(rx.ephemeris.prn),
        az_deg=sky.az_deg.astype(np.float32),
        el_deg=sky.el_deg.astype(np.float32),
        crosses_building=sky.blocked & setup.valid[:, None],
    )


def split_seeds(seeds: tuple[int, ...], parts: int) -> list[tuple[int, ...]]:
    """Split seeds into at most ``parts`` contiguous groups (for parallel jobs)."""
    parts = max(1, min(parts, len(seeds)))
    return [tuple(int(s) for s in g) for g in np.array_split(np.asarray(seeds), parts) if len(g)]
