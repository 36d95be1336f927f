"""The real runs as the diagnosis holds them: each aligned with the simulator (its truth in a
scene frame, its power-on, the sky along it) and its log over the simulator's satellites, and an
ensemble read the same way (positions, HDOP and altitude rounded to the digits the log prints).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from virtualgps import geodesy
from virtualgps.gap.ensemble import Ensemble, Geometry, RunSetup, geometry_job, setup_digest
from virtualgps.gap.ingest import FULL_FIX_RECORDS
from virtualgps.gap.jobs import map_jobs
from virtualgps.gap.observed import Obs, RunView, position_quantum_min, printed_step, quantize
from virtualgps.gap.where import SKY_BIN_AZ_DEG, SKY_BIN_EL_DEG, errors_enu
from virtualgps.receiver.definition import Georef
from virtualgps.receiver.params import Profile
from virtualgps.sky import systems

SCENE_REACH_M = 5000.0
# The simulated receiver runs on through gaps in the truth of up to this many seconds, on the
# straight line between the truth's ends: the real one did not stop there, and a receiver
# that restarts after every gap (its filter, its held position) differs from it for the
# epochs after each (the GSDC drive's truth has 31 gaps of 4-69 s; a 1.7 s navigation filter
# injected into its fixes lags ~33 m where the restarted simulation lagged by nothing). Over
# the gaps of up to 10 s in that drive's own reference (its INS positions, printed with
# quality 0) the straight line lies within 0.0-8.6 m of the path; over 12-14 s, 10-30 m; over
# 69 s, 367 m. No epoch inside a gap is compared (TRUTH_MAX_GAP_S).
SIM_MAX_GAP_S = 10.0
# Truth epochs further apart than this are not differenced for the truth's velocity.
VEL_MAX_STEP_S = 5.0


@dataclass
class Run:
    """A run as the diagnosis holds it: its setup, its aligned real view, ingest facts."""

    setup: RunSetup
    view: RunView
    err_real: np.ndarray  # (1, n, 3)
    info: dict = field(default_factory=dict)


def _on_sim_columns(log_prn: np.ndarray, x: np.ndarray, prn: np.ndarray, fill: Any
                    ) -> np.ndarray:
    """A log's per-satellite array ``x`` (n, k_log), columns ``log_prn``, under the simulator's
    PRN columns ``prn`` (k,): (n, k), ``fill`` where the log never lists that satellite."""
    col = {int(p): c for c, p in enumerate(log_prn)}
    out = np.full((x.shape[0], prn.size), fill, dtype=x.dtype)
    for j, p in enumerate(prn):
        c = col.get(int(p))
        if c is not None:
            out[:, j] = x[:, c]
    return out


def _real_obs(epochs, prn: np.ndarray) -> Obs:
    """The real log's epochs as an :class:`Obs` over the simulator's PRN columns."""
    cn0 = _on_sim_columns(epochs.prn, epochs.cn0_dbhz, prn, np.nan)
    tracked = np.isfinite(cn0)
    used = _on_sim_columns(epochs.prn, epochs.used, prn, False)
    sep = np.where(np.isfinite(epochs.geoid_sep_m), epochs.geoid_sep_m,
                   geodesy.geoid_sep_m(np.nan_to_num(epochs.lat_deg),
                                       np.nan_to_num(epochs.lon_deg)))
    sats = np.where(epochs.sats_used >= 0, epochs.sats_used, np.nan).astype(float)
    # A receiver that uses systems the simulation lacks may count them all in its GGA (a
    # phone's GNGGA): where its GSA lists such satellites, the satellites used are the
    # simulated systems' ones its GSA lists (the Magdeburg phone's GGA counts exactly those).
    letters = systems.letters(epochs.prn)
    other = ~np.isin(letters, np.unique(systems.letters(prn)))
    if epochs.used[:, other].any():
        sats = np.where(epochs.sats_used_gsa >= 0, used.sum(axis=1), sats)
    # An epoch without a fix has no position, whatever it prints (MTK: 8960.0000,N 137.0 m)
    fix = epochs.quality > 0
    lat, lon = (np.where(fix, x, np.nan) for x in (epochs.lat_deg, epochs.lon_deg))
    return Obs(
        lat_deg=lat[None], lon_deg=lon[None],
        alt_hae_m=np.where(fix, epochs.alt_msl_m + sep, np.nan)[None],
        quality=epochs.quality[None].astype(np.int16),
        hdop=epochs.hdop[None], sats_used=sats[None], speed_mps=epochs.speed_mps[None],
        tracked=tracked[None], cn0_dbhz=cn0[None], used=used[None],
    )


def sim_obs(ens: Ensemble, view: RunView | None = None) -> Obs:
    """An ensemble as an :class:`Obs` (positions rounded like the run's real log)."""
    obs = Obs(
        lat_deg=ens.lat_deg, lon_deg=ens.lon_deg, alt_hae_m=ens.alt_hae_m,
        quality=ens.quality.astype(np.int16), hdop=ens.hdop.astype(float),
        sats_used=ens.used.sum(axis=2).astype(float), speed_mps=ens.speed_mps.astype(float),
        # (C/N0 stays float32: the ensemble's largest array, read by bins alone)
        tracked=np.isfinite(ens.cn0_dbhz), cn0_dbhz=ens.cn0_dbhz, used=ens.used,
    )
    return obs if view is None else quantize(obs, view.quantum_min, view.hdop_step,
                                             view.alt_step_m)


def prepare_runs(
    runs: Sequence[Any],
    scene: Any,
    scene_path: str | None,
    tle_path: str,
    profile: Profile,
    sky_shift: Callable[[float], float],
    jobs: int | None = None,
    dask: str | None = None,
    systems: str | None = None,
) -> list[Run]:
    """Align each real run with the simulator: its setup (truth in a scene frame, power-on),
    the sky geometry along it, and the real log over the simulator's satellites.

    Parameters
    ----------
    runs : :class:`virtualgps.gap.ingest.RealRun` values
    scene : the loaded scene (None: open sky); scene_path : its folder
    tle_path : the TLE set; profile : the profile under test (its elevation mask sets which
        satellites are compared)
    sky_shift : run start (UTC s) -> the sky-time shift to use (0: the true sky)
    jobs, dask : where the geometry jobs run (:func:`virtualgps.gap.jobs.map_jobs`)
    systems : RINEX letters of the systems compared (default: those the profile tracks)

    Returns
    -------
    runs : the prepared runs, in input order
    """
    from virtualgps.gap.ingest import truth_positions

    systems = systems or profile.constellations.letters()
    setups, pre = [], []
    for run in runs:
        ep = run.epochs
        t = np.asarray(ep.t_unix_s, dtype=float)
        georef = None
        if scene is not None:
            georef = Georef(scene.lat_deg, scene.lon_deg, scene.alt_hae_m)
        lat, lon, alt, valid = truth_positions(run, t, georef)
        lat, lon, alt = (np.where(valid, x, np.nan) for x in (lat, lon, alt))
        *posed_lla, posed = truth_positions(run, t, georef, SIM_MAX_GAP_S)
        posed |= valid
        if not valid.any():
            from virtualgps.exceptions import InputFileError

            truth_t = run.truth.track.t_unix_s if run.truth.track is not None else t[:0]
            raise InputFileError(run.path, "no epoch of this log matches its truth in time "
                                 f"(log {_utc_span(t)}, truth {_utc_span(truth_t)}); check the "
                                 "truth file, its time zone and its clock")
        _check_near(run, lat, lon, valid)
        where_scene = scene_path
        if georef is not None:
            enu = geodesy.ecef_to_enu(
                geodesy.geodetic_to_ecef(lat[valid], lon[valid], alt[valid]),
                georef.lat0_deg, georef.lon0_deg, georef.alt0_hae_m)
            if np.nanmax(np.hypot(enu[:, 0], enu[:, 1])) > SCENE_REACH_M:
                georef, where_scene = None, None
        if georef is None:
            k = np.flatnonzero(valid)[0]
            georef = Georef(float(lat[k]), float(lon[k]), float(alt[k]))
        ant = np.zeros((t.size, 3))
        ant[posed] = geodesy.ecef_to_enu(geodesy.geodetic_to_ecef(
            *(np.asarray(x)[posed] for x in posed_lla)),
            georef.lat0_deg, georef.lon0_deg, georef.alt0_hae_m)
        vel = truth_velocity_enu_mps(t, ant, posed)
        started = not (ep.quality[0] > 0 and np.isfinite(ep.lat_deg[0]))
        t_sim, shift = snap_epochs(t), sky_shift(float(t[0]))
        setups.append(RunSetup(
            key=run.name, t_unix_s=t_sim, antenna_enu_m=ant, vel_enu_mps=vel, valid=valid,
            power_on_unix_s=float(t[0]) if started else math.nan, georef=georef,
            scene_path=where_scene, tle_path=tle_path, sky_shift_s=shift,
            digest=setup_digest(t_sim, ant, posed, georef, where_scene, tle_path, shift,
                                systems, valid.tobytes()), systems=systems, posed=posed))
        pre.append((run, lat, lon, alt))
    geoms: list[Geometry] = map_jobs(geometry_job, setups, jobs=jobs, dask_address=dask)
    out = []
    mask = profile.sky.elevation_mask_deg
    for setup, geom, (run, lat, lon, alt) in zip(setups, geoms, pre, strict=True):
        ep = run.epochs
        real = _real_obs(ep, geom.prn)
        el = geom.el_deg.astype(float)
        listed = ep.in_view.any(axis=1) | (ep.sats_in_view >= 0)
        with np.errstate(invalid="ignore"):
            above = el >= mask
        sep_deg = _sky_separation_deg(ep, geom.prn, el, geom.az_deg.astype(float))
        sat_ok = above & listed[:, None] & setup.valid[:, None] & ~(sep_deg > SKY_SEP_MAX_DEG)
        sky, in_wrong = _sky_info(geom.prn, sep_deg)
        sat_ok[:, in_wrong] = False  # (nor a satellite the log never lists, in a wrong sky)
        silent = _silent_prns(real.tracked[0], el, geom.az_deg.astype(float), sat_ok
                              ) if run.has_cn0 else np.zeros(
            geom.prn.size, bool)
        sat_ok &= ~silent[None, :]
        reference = "median" if run.truth.kind == "static" else "truth"
        view = RunView(
            name=run.name, t_unix_s=setup.t_unix_s, power_on_unix_s=float(setup.t_unix_s[0]),
            started=bool(np.isfinite(setup.power_on_unix_s)),
            truth_lat_deg=lat, truth_lon_deg=lon, truth_alt_hae_m=alt, reference=reference,
            vel_enu_mps=setup.vel_enu_mps, near_building=(geom.crosses_building & above).any(1),
            prn=geom.prn, az_deg=geom.az_deg.astype(float), el_deg=el, sat_ok=sat_ok,
            assess={"gsv": bool(run.has_gsv), "cn0": bool(run.has_cn0),
                    "gsa": bool(run.has_gsa),
                    "gga": any(run.sentences.get(k) for k in FULL_FIX_RECORDS)},
            real=real, quantum_min=position_quantum_min(real.lat_deg[0], real.lon_deg[0]),
            hdop_step=printed_step(np.where(ep.quality > 0, ep.hdop, np.nan)),
            alt_step_m=printed_step(np.where(ep.quality > 0, ep.alt_msl_m, np.nan)),
        )
        out.append(Run(setup, view, errors_enu(view, real), {
            "skipped": dict(run.skipped), "sentences": dict(run.sentences),
            "dated_by": run.dated_by, "checksummed": bool(ep.checksummed),
            "time_offset_s": run.time_offset_s, "offset": dict(run.offset_info),
            "simulated_in": "scene" if setup.scene_path else "open sky",
            "silent_prns": [int(p) for p in geom.prn[silent]],
            "sky": sky,
        }))
    return out


def truth_velocity_enu_mps(t_unix_s: np.ndarray, antenna_enu_m: np.ndarray,
                           posed: np.ndarray) -> np.ndarray:
    """The truth's velocity, by finite differences along each stretch of ``posed`` epochs
    no more than VEL_MAX_STEP_S apart (one-sided at its ends); NaN where unknown (outside the
    stretches, and a stretch of one epoch), not 0: an epoch whose speed is unknown is neither
    moving nor stationary (after each gap in the GSDC drive's truth a 25 m/s epoch read 0
    and counted as stationary).

    t_unix_s : (n,) s; antenna_enu_m : (n, 3) metres; posed : (n,) bool; returns (n, 3) m/s
    """
    vel = np.full((t_unix_s.size, 3), np.nan)
    k = np.flatnonzero(posed)
    for part in np.split(k, np.flatnonzero(np.diff(t_unix_s[k]) > VEL_MAX_STEP_S) + 1):
        if part.size > 1:
            vel[part] = np.gradient(antenna_enu_m[part], t_unix_s[part], axis=0)
    return vel


# A log whose fixes lie this far from its truth (median) is of another place: no receiver's
# error, truth offset (a lever arm, a datum) or flat-earth conversion comes near (tens of metres
# at 25 km from a scene origin), while a sign left off a longitude or a latitude, degrees and
# minutes read as degrees, or a scene frame without its georeference all move it by more, and
# the sky above the truth is then another sky (one degree of elevation per 111 km).
TRUTH_FAR_M = 50_000.0


def _check_near(run: Any, lat_deg: np.ndarray, lon_deg: np.ndarray, valid: np.ndarray) -> None:
    """Raise an input error naming the log when its fixes lie a median TRUTH_FAR_M or more
    from its truth ``lat_deg``, ``lon_deg`` (n,) at the ``valid`` (n,) epochs."""
    from virtualgps.exceptions import InputFileError

    ep = run.epochs
    ok = valid & (ep.quality > 0) & np.isfinite(ep.lat_deg) & np.isfinite(ep.lon_deg)
    if not ok.any():
        return
    fix = geodesy.geodetic_to_ecef(ep.lat_deg[ok], ep.lon_deg[ok], 0.0)
    truth = geodesy.geodetic_to_ecef(lat_deg[ok], lon_deg[ok], 0.0)
    far_m = float(np.median(np.linalg.norm(fix - truth, axis=-1)))
    if far_m >= TRUTH_FAR_M:
        k = np.flatnonzero(ok)[0]
        raise InputFileError(
            run.path, f"its fixes lie a median {far_m / 1000.0:,.0f} km from its truth (fix "
            f"{ep.lat_deg[k]:.5f}, {ep.lon_deg[k]:.5f} against truth {lat_deg[k]:.5f}, "
            f"{lon_deg[k]:.5f}): not the same place; check the truth's signs (south and west "
            "negative), its units (degrees, not degrees and minutes) and, for scene "
            "coordinates, the scene's georeference")


def _utc_span(t_unix_s: np.ndarray) -> str:
    """``2020-05-14 22:10:46 to 22:39:44 UTC`` (the end's date where it differs)."""
    if not t_unix_s.size:
        return "empty"
    a, b = (time.gmtime(float(x)) for x in (t_unix_s[0], t_unix_s[-1]))
    end = time.strftime("%H:%M:%S" if a[:3] == b[:3] else "%Y-%m-%d %H:%M:%S", b)
    return f"{time.strftime('%Y-%m-%d %H:%M:%S', a)} to {end} UTC"


# A satellite the real receiver never tracks in a whole run, while at the same epochs it tracks
# most of the satellites lower in the sky, and over a pass long enough to cross several sky-mask
# bins (an obstruction the scene lacks would have to be that wide, and spare the lower
# satellites), is taken as not transmitting (unhealthy, or retired while the TLE set still lists
# it), not as blocked: it is left out of the tracking comparisons, where it would teach a sky
# mask to block its path. Over a short pass the two cannot be told apart and it stays compared.
SILENT_MIN_BINS = 3


def _silent_prns(real_tracked: np.ndarray, el_deg: np.ndarray, az_deg: np.ndarray,
                 sat_ok: np.ndarray) -> np.ndarray:
    """(k,) bool: PRNs never tracked in the run though the real receiver tracks most of the
    satellites below them at the epochs they are compared, over a pass crossing at least
    SILENT_MIN_BINS sky-mask bins. real_tracked, el_deg, az_deg, sat_ok : (n, k)."""
    k = sat_ok.shape[1]
    out = np.zeros(k, bool)
    never = sat_ok.any(axis=0) & ~(real_tracked & sat_ok).any(axis=0)
    el = np.nan_to_num(el_deg, nan=-90.0)
    for j in np.flatnonzero(never):
        ep = sat_ok[:, j]
        lower = sat_ok[ep] & (el[ep] < el[ep, j][:, None])
        lower[:, j] = False
        if not lower.any() or (lower & real_tracked[ep]).sum() <= 0.5 * lower.sum():
            continue
        bins = {(int(e // SKY_BIN_EL_DEG), int(a % 360.0 // SKY_BIN_AZ_DEG))
                for e, a in zip(el[ep, j], np.nan_to_num(az_deg[ep, j]), strict=True)}
        out[j] = len(bins) >= SILENT_MIN_BINS
    return out


# A satellite whose GSV elevation and azimuth lie this far from where the ephemeris puts it
# (median over the run) is not the satellite the simulation has under that number: GSV prints
# whole degrees (0.4 deg of rounding on average), SGP4 within 60 days of its TLE epoch stays at
# that floor against a real receiver's GSV (ephemeris.sidereal_shift_s), and a phone's own
# constant offset is 1.8 deg (the Magdeburg logs, ../shared/data/SOURCES.md); a sky shifted to
# the same sidereal time three years away is 9 deg off on average, a satellite being relocated
# degrees per day. Such a satellite is left out of the tracking comparisons, where its real
# tracking would be compared with another sky position's simulated one.
SKY_SEP_MAX_DEG = 5.0


def _sky_separation_deg(epochs, prn: np.ndarray, el_deg: np.ndarray, az_deg: np.ndarray
                        ) -> np.ndarray:
    """(k,) the median angle, degrees, between where the log's GSV puts each simulated PRN and
    where the ephemeris does, over the epochs the log gives its elevation and azimuth (NaN:
    never). epochs : the log's; prn : (k,); el_deg, az_deg : (n, k) simulated, degrees."""
    real_el = _on_sim_columns(epochs.prn, epochs.el_deg, prn, np.nan)
    real_az = _on_sim_columns(epochs.prn, epochs.az_deg, prn, np.nan)
    ok = np.isfinite(real_el) & np.isfinite(real_az) & np.isfinite(el_deg) & np.isfinite(az_deg)
    cos = np.sum(geodesy.azel_to_enu_unit(np.where(ok, real_az, 0.0), np.where(ok, real_el, 0.0))
                 * geodesy.azel_to_enu_unit(np.where(ok, az_deg, 0.0), np.where(ok, el_deg, 0.0)),
                 axis=-1)
    sep = np.where(ok, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), np.nan)
    out = np.full(prn.size, np.nan)
    seen = ok.any(axis=0)
    out[seen] = np.nanmedian(sep[:, seen], axis=0)
    return out


def _sky_info(prn: np.ndarray, sep_deg: np.ndarray) -> tuple[dict, np.ndarray]:
    """How the log's sky matches the simulated one: PRNs compared, their median separation
    (degrees), those beyond SKY_SEP_MAX_DEG ("misplaced"), and the systems most of whose
    compared PRNs are (``wrong``: that system's simulated sky is not the log's, and none of its
    satellites is compared; per system, as a system's numbering, GLONASS slots, may be what
    is off), and a (k,) bool mask of the wrong systems' satellites. prn, sep_deg : (k,)."""
    seen = np.isfinite(sep_deg)
    off = seen & (sep_deg > SKY_SEP_MAX_DEG)
    letters = systems.letters(prn)
    wrong = [x for x in dict.fromkeys(letters[seen].tolist())
             if x != "?" and 2 * off[letters == x].sum() > seen[letters == x].sum()]
    return {"prns_compared": int(seen.sum()),
            "median_sep_deg": round(float(np.median(sep_deg[seen])), 2) if seen.any() else None,
            "misplaced_prns": [int(p) for p in prn[off]], "max_sep_deg": SKY_SEP_MAX_DEG,
            "wrong": [systems.system_named(x).name for x in wrong]}, np.isin(letters, wrong)


def snap_epochs(t_unix_s: np.ndarray) -> np.ndarray:
    """Epoch times on whole multiples of the log's period where they lie within a quarter
    period of one (real receivers' time tags jitter by milliseconds; on the grid the
    receiver's Gauss-Markov recursions take equal steps), else unchanged.

    t_unix_s : (n,) float, UTC seconds, increasing; returns (n,) float
    """
    t = np.asarray(t_unix_s, dtype=float)
    if t.size < 2:
        return t
    period = float(np.median(np.diff(t)))
    if not period > 0:
        return t
    rate = 1.0 / period
    k = np.rint(t * rate)
    near = np.abs(t - k / rate) <= 0.25 * period
    return np.where(near, k / rate, t)


# --- simulating ---------------------------------------------------------------------------------
