"""Simulated counterparts of the real MTK logs, for calibrating a receiver profile.

The simulated column of the ``holux-m1000`` calibration table is made exactly like the real one:
the receiver is replayed where and when the real log was recorded (the same core and NMEA
writer as ``virtualgps replay``), its NMEA is read back with the reader the real log goes
through, and :func:`virtualgps.gap.metrics.summary` computes the same statistics. Integer SNR, the
4-decimal minutes of the position and the 2-decimal HDOP are then rounded alike on both sides.

- MT3339 static hour: the antenna stands at the log's median position from the log's first
  epoch to its last; the satellites come from the 2017-03-26 CelesTrak set (15 days after the
  log; it reproduces the log's GSV angles to about 0.4 deg, SOURCES.md), propagated straight to
  the log's time (no sky shift: SGP4 is better than a shift for at least 50 days,
  :func:`virtualgps.sky.ephemeris.sidereal_shift_s`). No scene: the log holds no map.
- M-241 car track (2008): the antenna follows the logged positions (their own error, a few
  metres, is irrelevant to satellite counts and HDOP). No TLE of 2008 is at hand, so the track
  is replayed at the same UTC time of day on several days around that set's epoch
  (``M241_START_DAYS``): the satellite counts and HDOP of a moving receiver at that latitude,
  not of that afternoon's sky.

A one-hour record of an error correlated over ~150 s holds only ~12 independent samples, so
its statistics scatter from seed to seed by 10-20 %. The simulated value of each statistic is
the median over several seeds, and the seed-to-seed spread is reported beside it.

- Magdeburg waypoints (:func:`waypoint_sky`): the phone's 14 static logs on the campus, each
  at its map marker, against the receiver walked along the same markers through the campus
  mesh: how often, and how much weaker, satellites whose direct path crosses a building are
  still tracked.
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from mtk_logs import (
    M241_MOVING_MIN_SPEED_MPS,
    M241_TRACK_CSV,
    MT3339_STATIC_LOG,
    read_mtk_logger_csv,
)

from virtualgps import geodesy
from virtualgps.device import nmea
from virtualgps.device.nmea import NmeaEpochs, nmea_epochs_from_lines, read_nmea_epochs
from virtualgps.gap.ingest import take_epochs
from virtualgps.gap.metrics import ELEVATION_BINS_DEG, median_position, summary
from virtualgps.poses import pose
from virtualgps.receiver.definition import Georef, Receiver
from virtualgps.receiver.params import Profile
from virtualgps.receiver.profiles import load_profile
from virtualgps.receiver.skyview import compute_sky
from virtualgps.run.replay import epoch_grid, run_replay, track_in_scene
from virtualgps.sky.ephemeris import Constellation, load_tle

# The TLE set nearest the MT3339 hour (2017-03-11) among ../shared/data (SOURCES.md).
CALIBRATION_TLE = "magdeburg-campus/tle/gps-ops.2017-03-26.tle.txt"
DEFAULT_SEEDS = tuple(range(8))
M241_START_DAYS = (-3, -2, -1, 0, 1, 2, 3)  # days from the TLE set's epoch, same time of day


@dataclass(frozen=True)
class Statistic:
    """One row of the calibration table.

    key : the :func:`virtualgps.gap.metrics.summary` key
    log : "mt3339_static" or "m241_moving"
    label : what docs/profiles.md calls it
    tolerance : allowed |sim / real - 1| (the issue's +-20 %); None: shown, not calibrated
    abs_tolerance : allowed |sim - real| instead (dB-Hz, shares), where a ratio means little
    """

    key: str
    log: str
    label: str
    tolerance: float | None = 0.20
    abs_tolerance: float | None = None


def _bin_rows() -> tuple[Statistic, ...]:
    """Per elevation bin, the median C/N0 within 3 dB and the share tracked within 15 points
    (pooled quartiles hid a wrong shape: a 5 dB shift of the zenith C/N0 moved the pooled
    median by only 2 dB)."""
    rows = []
    for lo, hi in ELEVATION_BINS_DEG:
        rows.append(Statistic(f"cn0_el{lo}_{hi}_median_dbhz", "mt3339_static",
                              f"C/N0 median at {lo}-{hi} deg (dB-Hz)", None, 3.0))
    for lo, hi in ELEVATION_BINS_DEG:
        rows.append(Statistic(f"tracked_el{lo}_{hi}_share", "mt3339_static",
                              f"share tracked at {lo}-{hi} deg", None, 0.15))
    return tuple(rows)


# The statistics the profile is calibrated to reproduce (CEP50, R95, the error
# autocorrelation time, satellites used, the HDOP distribution; C/N0 and tracking
# per elevation bin, satellites used and the VDOP of the used sets within 10 %). The MT3339
# rows are simulated with the log's site (the obstruction ``virtualgps gap`` learned,
# ``tools/mt3339-site.toml``) on top of the profile's open-sky antenna.
STATISTICS = (
    Statistic("cep50_m", "mt3339_static", "CEP50 (m)"),
    Statistic("r95_m", "mt3339_static", "R95 (m)"),
    Statistic("autocorr_h_s", "mt3339_static", "error autocorrelation 1/e, horizontal (s)"),
    Statistic("sats_used_mean", "mt3339_static", "satellites used, mean", 0.10),
    Statistic("vdop_used_median", "mt3339_static", "VDOP of the used sets, median", 0.10),
    Statistic("hdop_p25", "mt3339_static", "HDOP 25 %"),
    Statistic("hdop_median", "mt3339_static", "HDOP median"),
    Statistic("hdop_p75", "mt3339_static", "HDOP 75 %"),
    *_bin_rows(),
    Statistic("sats_used_mean", "m241_moving", "satellites used, mean"),
    Statistic("hdop_median", "m241_moving", "HDOP median"),
    Statistic("hdop_p75", "m241_moving", "HDOP 75 %"),
    Statistic("speed_median_kn", "mt3339_static", "speed while static, median (kn)"),
    # Shown for what they say about the model's limits, not calibrated: one hour of a
    # correlated error fixes the axes' ratio only loosely, and MTK smooths its height (the
    # simulated vertical error follows VDOP); the used set changes more often in reality.
    Statistic("sigma_e_m", "mt3339_static", "1-sigma east (m)", None),
    Statistic("sigma_n_m", "mt3339_static", "1-sigma north (m)", None),
    Statistic("sigma_u_m", "mt3339_static", "1-sigma up (m)", None),
    Statistic("sats_used_changes_per_min", "mt3339_static", "used-set changes per minute", None),
    Statistic("sats_used_changes_per_min", "m241_moving", "used-set changes per minute", None),
    # Doppler speed noise: the median is fitted; the real hour's tail is heavier than a
    # Gaussian velocity error's, and its course changes as often as the simulated one's.
    Statistic("speed_p90_kn", "mt3339_static", "speed while static, 90 % (kn)", None),
    Statistic("course_change_share", "mt3339_static", "share of epochs whose course changes",
              None),
    # Fixed by the ephemeris and the place, whatever the receiver does: shown, not calibrated.
    Statistic("sats_in_view_gps_mean", "mt3339_static", "GPS satellites in view, mean", None),
    Statistic("sats_in_view_mean", "m241_moving", "satellites in view, mean", None),
    Statistic("cn0_median_dbhz", "mt3339_static", "C/N0 median, pooled (dB-Hz)", None),
)


# The M-241 car track's site: the logger rode inside a car, whose roof edge and the roadside
# (trees, houses, bridges) take the sky below 15 deg; fitted by hand to the track's satellites
# used and HDOP (no GSV to learn it from: the logger's CSV has no per-satellite directions).
# 10 dB leaves every low satellite in the fix (9.8 used, HDOP 0.90); 15 dB: 7.8 and 1.18.
M241_SITE = {"sky_mask": {"enabled": True, "az_bin_deg": 360.0, "el_bin_deg": 15.0,
                          "atten_db": [[15.0]]}}


def site_profile(name_or_path: str, site: str | Path | dict,
                 overrides_path: str | Path | None = None) -> Profile:
    """A profile at a real log's site: its ``[sky_mask]`` (the obstruction ``virtualgps gap``
    learned there, a TOML file such as ``tools/mt3339-site.toml``, or a table such as
    :data:`M241_SITE`) on top of the profile and its overrides."""
    import tomllib

    if not isinstance(site, dict):
        with open(site, "rb") as f:
            site = tomllib.load(f)
    return load_profile(name_or_path, {"sky_mask": site["sky_mask"]}, overrides_path)


def replay_epochs(
    profile: Profile,
    ephemeris: Constellation,
    georef: Georef,
    track: pose.PoseTrack,
    seed: int,
) -> NmeaEpochs:
    """Replay poses through the receiver and read its NMEA back as a real log is read.

    Parameters
    ----------
    profile : the receiver profile
    ephemeris : the satellites
    georef : the scene origin the poses are relative to
    track : the antenna's poses (ENU of ``georef``, or geodetic)
    seed : random seed

    Returns
    -------
    epochs : :class:`virtualgps.device.nmea.NmeaEpochs` of the simulated receiver's output
    """
    rx = Receiver(profile=profile, ephemeris=ephemeris, scene=None, georef=georef)
    return replay_epochs_in(rx, track_in_scene(track, georef), seed)


def replay_epochs_in(rx: Receiver, track: pose.PoseTrack, seed: int) -> NmeaEpochs:
    """:func:`replay_epochs` with a prepared receiver (e.g. one in a scene).

    Parameters
    ----------
    rx : the receiver
    track : the antenna's poses, ENU of the receiver's georeference
    seed : random seed

    Returns
    -------
    epochs : :class:`virtualgps.device.nmea.NmeaEpochs` of the simulated receiver's output
    """
    grid = epoch_grid(track.t_unix_s, rx.profile.rate_hz, None)
    out = io.BytesIO()
    run_replay(rx, track, grid, nmea.NmeaFormat.from_dict(rx.profile.nmea), out, seed)
    return nmea_epochs_from_lines(out.getvalue().decode("ascii").splitlines(), "<simulated>")


def mt3339_setup(root: Path) -> tuple[Georef, pose.PoseTrack]:
    """Where the MT3339 stood (its median fix), standing there over its log's span."""
    real = read_nmea_epochs(root / MT3339_STATIC_LOG)
    fixed = (real.quality > 0) & np.isfinite(real.lat_deg) & np.isfinite(real.alt_msl_m)
    lat, lon = real.lat_deg[fixed], real.lon_deg[fixed]
    sep = real.geoid_sep_m[fixed]
    alt_hae = real.alt_msl_m[fixed] + np.where(np.isfinite(sep), sep, geodesy.geoid_sep_m(lat, lon))
    lat, lon, alt = median_position(lat, lon, alt_hae)
    t = np.arange(np.floor(real.t_unix_s[0]), np.ceil(real.t_unix_s[-1]) + 1.0)
    track = pose.PoseTrack(t, "enu", np.zeros((t.size, 3)), np.full((t.size, 3), np.nan))
    return Georef(float(lat), float(lon), float(alt)), track


def m241_setup(root: Path) -> tuple[Georef, pose.PoseTrack, np.ndarray]:
    """The M-241 track as geodetic poses, its first point as origin, and its speeds (m/s)."""
    trk = read_mtk_logger_csv(root / M241_TRACK_CSV)
    # The logger writes a record per reason (time, speed, distance): some share a second.
    first = np.concatenate([[True], np.diff(trk.t_unix_s) > 0])
    ok = first & np.isfinite(trk.lat_deg) & np.isfinite(trk.alt_hae_m)
    xyz = np.stack([trk.lat_deg[ok], trk.lon_deg[ok], trk.alt_hae_m[ok]], axis=-1)
    track = pose.PoseTrack(trk.t_unix_s[ok], "geodetic", xyz, np.full(xyz.shape, np.nan))
    return Georef(*(float(v) for v in xyz[0])), track, trk.speed_mps[ok]


def days_to_epoch_s(ephemeris: Constellation, t_unix_s: float) -> float:
    """Whole days (in seconds) from ``t_unix_s`` to the TLE set's epoch: a shift that keeps the
    UTC time of day (the M-241's 2008 track replayed near a 2017 set)."""
    return 86400.0 * round((ephemeris.epoch_center_unix_s - t_unix_s) / 86400.0)


def sim_calibration_stats(
    profile: Profile,
    shared_data_dir: str | Path,
    seeds: Sequence[int] = DEFAULT_SEEDS,
    progress: Callable[[str], None] | None = None,
    mt3339_profile: Profile | None = None,
    m241_profile: Profile | None = None,
) -> dict[str, dict[str, list[float]]]:
    """The simulated column of the calibration table: statistics of each seed's run.

    Parameters
    ----------
    profile : the receiver profile to check (e.g. ``load_profile("holux-m1000")``)
    mt3339_profile, m241_profile : the same at each log's site (:func:`site_profile`);
        default ``profile``
    shared_data_dir : the ``../shared/data`` folder (logs and the TLE set)
    seeds : one MT3339 hour and one M-241 replay per seed (the M-241 on the day
        ``M241_START_DAYS[i % len]`` from the TLE's epoch)
    progress : called with a short text after each run

    Returns
    -------
    stats : {"mt3339_static" | "m241_moving": {summary key: [value per seed]}}
    """
    root = Path(shared_data_dir)
    ephemeris = load_tle(root / CALIBRATION_TLE)
    out: dict[str, dict[str, list[float]]] = {"mt3339_static": {}, "m241_moving": {}}

    georef, track = mt3339_setup(root)
    for seed in seeds:
        s = summary(replay_epochs(mt3339_profile or profile, ephemeris, georef, track, seed),
                    "median")
        for k, v in s.items():
            out["mt3339_static"].setdefault(k, []).append(v)
        if progress is not None:
            progress(f"MT3339 hour, seed {seed}")

    georef, track, speed = m241_setup(root)
    t = track.t_unix_s
    day_shift_s = days_to_epoch_s(ephemeris, float(t[0]))
    for i, seed in enumerate(seeds):
        shift = day_shift_s + 86400.0 * M241_START_DAYS[i % len(M241_START_DAYS)]
        shifted = replace(track, t_unix_s=t + shift)
        ep = replay_epochs(m241_profile or profile, ephemeris, georef, shifted, seed)
        # The real statistic is over the records logged while moving: the same epochs here.
        moving_t = t[speed >= M241_MOVING_MIN_SPEED_MPS] + shift
        keep = np.isin(np.round(ep.t_unix_s), np.round(moving_t))
        s = summary(take_epochs(ep, keep), reference=None)
        for k, v in s.items():
            out["m241_moving"].setdefault(k, []).append(v)
        if progress is not None:
            progress(f"M-241 track, seed {seed}")
    return out


@dataclass(frozen=True)
class Row:
    """One compared statistic: the real value, the simulated median and spread over seeds."""

    stat: Statistic
    real: float
    sim_median: float
    sim_min: float
    sim_max: float

    @property
    def ratio(self) -> float:
        """sim / real."""
        return self.sim_median / self.real

    @property
    def ok(self) -> bool | None:
        """Within the tolerance (None for a statistic that is not calibrated)."""
        if self.stat.abs_tolerance is not None:
            return bool(abs(self.sim_median - self.real) <= self.stat.abs_tolerance)
        if self.stat.tolerance is None:
            return None
        return bool(abs(self.ratio - 1.0) <= self.stat.tolerance)


def compare(
    real: dict[str, dict[str, float]], sim: dict[str, dict[str, list[float]]]
) -> list[Row]:
    """Real vs simulated for every statistic of :data:`STATISTICS`.

    Parameters
    ----------
    real : from :func:`mtk_logs.real_calibration_stats`
    sim : from :func:`sim_calibration_stats`

    Returns
    -------
    rows : one per statistic, in :data:`STATISTICS` order
    """
    rows = []
    for st in STATISTICS:
        v = np.asarray(sim[st.log][st.key], dtype=float)
        rows.append(Row(st, float(real[st.log][st.key]), float(np.median(v)),
                        float(np.min(v)), float(np.max(v))))
    return rows


# --- the open-sky antenna against the gpsd MTK captures --------------------------------------

# gpsd's regression captures of MediaTek receivers (SOURCES.md): short, in the open or near a
# window, every satellite listed with its elevation and SNR.
GPSD_MTK_CAPTURES = ("gpsd-mtk/mt3339.log", "gpsd-mtk/mtk-3301.log", "gpsd-mtk/mtk-3329.log",
                     "gpsd-mtk/bt-q818.log", "gpsd-mtk/tr737A+.log")


def capture_bins(profile: Profile, shared_data_dir: str | Path) -> list[dict[str, float]]:
    """Per elevation bin, the captures' SNR against the profile's open-sky C/N0 at the same
    satellite-epochs (``cn0_zenith_dbhz`` + the antenna gain, no fades, no site).

    Returns one dict per bin of :data:`ELEVATION_BINS_DEG`: ``lo_deg``, ``hi_deg``, ``n``
    (tracked satellite-epochs), ``real_median_dbhz``, ``model_median_dbhz``,
    ``real_min_dbhz``/``real_max_dbhz`` (the lowest and highest of the captures' own medians)
    """
    from virtualgps.receiver.signals import antenna_gain_db

    ct = profile.cn0_tracking
    el_all, cn0_all, which = [], [], []
    for i, rel in enumerate(GPSD_MTK_CAPTURES):
        ep = read_nmea_epochs(Path(shared_data_dir) / rel)
        gps = (ep.prn >= 1) & (ep.prn <= 32)
        el, cn0 = ep.el_deg[:, gps], ep.cn0_dbhz[:, gps]
        ok = np.isfinite(el) & np.isfinite(cn0)
        el_all.append(el[ok])
        cn0_all.append(cn0[ok])
        which.append(np.full(int(ok.sum()), i))
    el, cn0, which = (np.concatenate(a) for a in (el_all, cn0_all, which))
    model = ct.cn0_zenith_dbhz + antenna_gain_db(el, ct.horizon_loss_db)
    out = []
    for lo, hi in ELEVATION_BINS_DEG:
        m = (el >= lo) & ((el < hi) if hi < 90 else (el <= hi))
        own = [float(np.median(cn0[m & (which == i)])) for i in np.unique(which[m])]
        out.append({"lo_deg": lo, "hi_deg": hi, "n": int(m.sum()),
                    "real_median_dbhz": float(np.median(cn0[m])) if m.any() else math.nan,
                    "model_median_dbhz": float(np.median(model[m])) if m.any() else math.nan,
                    "real_min_dbhz": min(own, default=math.nan),
                    "real_max_dbhz": max(own, default=math.nan)})
    return out


# --- Magdeburg waypoints: blocked satellites, real phone vs simulated receiver ---------------

MAGDEBURG_TLE = "magdeburg-campus/tle/gps-ops.2017-03-28.tle.txt"
WAYPOINT_LOGS = "magdeburg-campus/nmea/Wegpunkte"
WAYPOINT_MARKERS = slice(4, 18)  # markers 5-18 of staticmap.txt: the logs in time order
ANTENNA_HEIGHT_M = 1.5  # a phone held in the hand (SOURCES.md)


@dataclass(frozen=True)
class WaypointSky:
    """Satellite-epochs at the Magdeburg waypoints above the elevation mask, real and simulated.

    Each array is (n,) over the satellite-epochs of GPS PRNs with a line of sight above the
    mask at the 14 waypoint logs (geometry from SGP4 with that day's TLEs and the campus mesh,
    the antenna 1.5 m above the ground at the marker).

    log : index of the log (0-13, time order); prn : PRN; el_deg : elevation, degrees
    crosses_building : the direct path hits an occluder of the mesh
    real_cn0_dbhz, sim_cn0_dbhz : GSV SNR of the phone / the simulated receiver, NaN where the
        satellite was not tracked
    """

    log: np.ndarray
    prn: np.ndarray
    el_deg: np.ndarray
    crosses_building: np.ndarray
    real_cn0_dbhz: np.ndarray
    sim_cn0_dbhz: np.ndarray


def waypoint_markers(root: Path) -> np.ndarray:
    """(18, 2) latitude, longitude (degrees) of the markers in ``staticmap.txt``."""
    url = (root / WAYPOINT_LOGS / "staticmap.txt").read_text()
    pairs = re.findall(r"(-?\d+\.\d+),(-?\d+\.\d+)\|", url)
    return np.array(pairs, dtype=float)


def waypoint_antennas(root: Path, scene) -> tuple[list[Path], list[np.ndarray]]:
    """The 14 Magdeburg waypoint logs in time order and their antennas: markers 5-18 of
    ``staticmap.txt``, 1.5 m above the campus mesh's ground (SOURCES.md).

    Returns
    -------
    logs : the log files, in time order
    antennas : (3,) scene-ENU metres per log
    """
    paths = sorted((Path(root) / WAYPOINT_LOGS).glob("NMEA_Log*.txt"))
    first = [float(np.nanmin(read_nmea_epochs(p).t_unix_s)) for p in paths]
    paths = [p for _, p in sorted(zip(first, paths, strict=True))]
    markers = waypoint_markers(Path(root))[WAYPOINT_MARKERS]
    if len(paths) != len(markers):
        raise ValueError(f"{len(paths)} waypoint logs for {len(markers)} markers")
    antennas = []
    for lat, lon in markers:
        enu = geodesy.ecef_to_enu(geodesy.geodetic_to_ecef(lat, lon, scene.alt_hae_m),
                                  scene.lat_deg, scene.lon_deg, scene.alt_hae_m)
        up = float(np.asarray(scene.ground_height_m(enu[0], enu[1]))) + ANTENNA_HEIGHT_M
        antennas.append(np.array([enu[0], enu[1], up]))
    return paths, antennas


def waypoint_truths(root: Path, scene) -> tuple[list[Path], list[str]]:
    """The Magdeburg waypoint logs and their truths as ``virtualgps gap`` takes them
    (``static:LAT,LON,ALT_HAE`` at each marker, 1.5 m above the mesh ground)."""
    paths, antennas = waypoint_antennas(root, scene)
    truths = []
    for a in antennas:
        lat, lon, alt = geodesy.ecef_to_geodetic(geodesy.enu_to_ecef(
            a, scene.lat_deg, scene.lon_deg, scene.alt_hae_m))
        truths.append(f"static:{float(lat):.9f},{float(lon):.9f},{float(alt):.3f}")
    return paths, truths


def waypoint_sky(
    profile: Profile, shared_data_dir: str | Path, scene, seed: int = 0
) -> WaypointSky:
    """Replay the profile along the Magdeburg waypoints: standing at each for its log's span,
    walking between them.

    Parameters
    ----------
    profile : the receiver profile (its ``nlos`` and ``cn0_tracking`` decide what is tracked)
    shared_data_dir : the ``../shared/data`` folder
    scene : the Magdeburg campus scene (``scenes/magdeburg-campus``)
    seed : random seed of the replay

    Returns
    -------
    sky : WaypointSky
    """
    root = Path(shared_data_dir)
    ephemeris = load_tle(root / MAGDEBURG_TLE)
    georef = Georef(scene.lat_deg, scene.lon_deg, scene.alt_hae_m)
    paths, antennas = waypoint_antennas(root, scene)
    logs = [read_nmea_epochs(p) for p in paths]
    # The geometry alone: which direct paths cross a building (no reflections considered).
    bare = Receiver(replace(profile, nlos=replace(profile.nlos, enabled=False)), ephemeris,
                    scene, georef)
    rx = Receiver(profile, ephemeris, scene, georef)
    spans = []
    for real in logs:
        t_real = real.t_unix_s[np.isfinite(real.t_unix_s)]
        spans.append(np.arange(np.ceil(t_real.min()), np.floor(t_real.max()) + 1.0))
    # The phone was carried from waypoint to waypoint with its receiver on: one run, walking
    # in straight lines between the markers, so tracking carries over as it did in reality.
    knots_t = np.concatenate([[sp[0], sp[-1]] for sp in spans])
    knots = np.repeat(np.stack(antennas), 2, axis=0)
    t_all = np.arange(knots_t[0], knots_t[-1] + 1.0)
    walk = np.stack([np.interp(t_all, knots_t, knots[:, a]) for a in range(3)], axis=1)
    sim = replay_epochs_in(rx, pose.PoseTrack(t_all, "enu", walk, np.full(walk.shape, np.nan)),
                           seed)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in WaypointSky.__dataclass_fields__}
    for i, (real, t, ant) in enumerate(zip(logs, spans, antennas, strict=True)):
        sky = compute_sky(bare, t, np.broadcast_to(ant, (t.size, 3)))
        k_t, k_s = np.nonzero(sky.above_mask)
        parts["log"].append(np.full(k_t.size, i))
        parts["prn"].append(ephemeris.prn[k_s])
        parts["el_deg"].append(sky.el_deg[k_t, k_s])
        parts["crosses_building"].append(sky.blocked[k_t, k_s])
        for name, ep in (("real_cn0_dbhz", real), ("sim_cn0_dbhz", sim)):
            parts[name].append(_cn0_at(ep, t[k_t], ephemeris.prn[k_s]))
    return WaypointSky(**{k: np.concatenate(v) for k, v in parts.items()})


def _cn0_at(epochs: NmeaEpochs, t_unix_s: np.ndarray, prn: np.ndarray) -> np.ndarray:
    """GSV SNR of each (time, PRN) in a log (NaN where not listed, not tracked or no epoch)."""
    row = {round(float(t)): i for i, t in enumerate(epochs.t_unix_s) if np.isfinite(t)}
    col = {int(p): j for j, p in enumerate(epochs.prn)}
    i = np.array([row.get(round(float(t)), -1) for t in t_unix_s])
    j = np.array([col.get(int(p), -1) for p in prn])
    ok = (i >= 0) & (j >= 0)
    out = np.full(t_unix_s.shape, np.nan)
    out[ok] = epochs.cn0_dbhz[i[ok], j[ok]]
    return out


def blocked_pattern(sky: WaypointSky, which: str) -> dict[str, float]:
    """How satellites whose direct path crosses a building are received.

    Parameters
    ----------
    sky : from :func:`waypoint_sky`
    which : "real" or "sim"

    Returns
    -------
    pattern : ``tracked_blocked`` and ``tracked_clear`` (fractions of satellite-epochs tracked),
        ``weaker_db`` (per PRN, the mean C/N0 of its tracked blocked epochs minus that of its
        tracked clear ones, averaged over the PRNs having both), ``n_blocked`` (satellite-epochs)
    """
    cn0 = sky.real_cn0_dbhz if which == "real" else sky.sim_cn0_dbhz
    tracked, blocked = np.isfinite(cn0), sky.crosses_building
    diffs = []
    for p in np.unique(sky.prn):
        b, c = tracked & blocked & (sky.prn == p), tracked & ~blocked & (sky.prn == p)
        if b.any() and c.any():
            diffs.append(cn0[b].mean() - cn0[c].mean())
    return {
        "tracked_blocked": float(tracked[blocked].mean()) if blocked.any() else float("nan"),
        "tracked_clear": float(tracked[~blocked].mean()) if (~blocked).any() else float("nan"),
        "weaker_db": float(-np.mean(diffs)) if diffs else float("nan"),
        "n_blocked": float(blocked.sum()),
    }


PATTERN_SEEDS = 5  # a single seed's C/N0 difference moves by +-0.6 dB (7.7-8.9 over seeds 0-5)


def sim_blocked_pattern(profile: Profile, shared_data_dir: str | Path, scene,
                        seeds: int = PATTERN_SEEDS) -> dict[str, float]:
    """:func:`blocked_pattern` of the simulated receiver at the Magdeburg waypoints, each
    statistic the median over ``seeds`` replays (seeds 0 .. seeds-1).

    Returns
    -------
    pattern : as :func:`blocked_pattern` ("sim"), medians over the seeds
    """
    runs = [blocked_pattern(waypoint_sky(profile, shared_data_dir, scene, s), "sim")
            for s in range(seeds)]
    out = {}
    for k in runs[0]:
        v = np.array([r[k] for r in runs])
        out[k] = float(np.median(v[np.isfinite(v)])) if np.isfinite(v).any() else float("nan")
    return out

