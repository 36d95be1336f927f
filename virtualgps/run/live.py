"""One receiver of the live loop: its command link, output format, device and counters.

:class:`LiveReceiver` holds what one receiver of :mod:`virtualgps.run.daemon`'s loop keeps
between epochs (its state and random stream, rate, output format and device) and answers what
its client writes (MTK ``$PMTK`` commands or UBX messages) between epochs; the loop decides
when its epochs are computed and sent.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from virtualgps.device import mtk, nmea
from virtualgps.device.ubx.link import UbxLink
from virtualgps.device.ubx.settings import Nav5
from virtualgps.device.ubx.settings import default_settings as ubx_defaults
from virtualgps.receiver.definition import Receiver
from virtualgps.receiver.params import Profile, SkyParams
from virtualgps.receiver.state import ReceiverRows, ReceiverState, initial_state, restart
from virtualgps.run.poseproviders import SimClock
from virtualgps.sky import systems as sky_systems

log = logging.getLogger(__name__)


@dataclass
class DaemonStats:
    """Counters the status line and the exit summary show.

    link : the command link (its ``settings`` are what the client set: with MTK fix interval,
        baud, sentence rates, SBAS, static-navigation threshold; with u-blox baud, protocols,
        message rates, navigation rate, GNSS, dynamic model), or None without one
    """

    epochs: int = 0
    fixes: int = 0
    last_fix: bool = False  # whether the last epoch sent had a fix
    # (late: sent over half a period after their time; skipped: the loop fell behind by over a
    # period, e.g. a suspended machine; thinned: left out to keep up, see Thinning)
    late_epochs: int = 0
    skipped_epochs: int = 0
    thinned_epochs: int = 0
    max_lateness_s: float = 0.0
    link: mtk.MtkLink | UbxLink | None = None


def make_link(profile, fmt: nmea.NmeaFormat) -> mtk.MtkLink | UbxLink | None:
    """The profile's command link: a :class:`~virtualgps.device.mtk.MtkLink` for ``mtk``, a
    :class:`~virtualgps.device.ubx.link.UbxLink` for ``ubx``, else None.

    Parameters
    ----------
    profile : the receiver profile (``command_link``, ``firmware``, ``rate_hz``, ``baud``)
    fmt : its output format (the sentences and their rates at power-on)

    Returns
    -------
    link : MtkLink, UbxLink or None
    """
    kind = getattr(profile, "command_link", "none")
    if kind == "ubx":
        return make_ubx_link(profile)
    if kind != "mtk":
        return None
    sbas = profile.sbas.enabled
    hold = profile.static_hold
    defaults = mtk.default_settings(
        fmt.sentences, dict(fmt.every), profile.rate_hz, profile.baud,
        dgps_mode=2 if sbas else 0, sbas_enabled=sbas,
        static_nav_mps=hold.threshold_mps if hold.enabled else 0.0,
    )
    return mtk.MtkLink(defaults, profile.firmware)


def make_ubx_link(profile) -> UbxLink:
    """A u-blox link at the profile's power-on: its generation (``[ubx]``), baud, rate, the
    systems it tracks enabled (SBAS where ``[sbas]`` is on), and its masks as CFG-NAV5's
    minElev (``sky.elevation_mask_deg``, rounded) and pDop (``sky.pdop_mask``; none as the
    largest, 6553.5).

    profile : the receiver profile; returns the UbxLink
    """
    systems = list(profile.constellations.systems if profile.constellations.enabled
                   else ("GPS",))
    if profile.sbas.enabled:
        systems.append("SBAS")
    defaults = ubx_defaults(profile.ubx.generation, baud=profile.baud, rate_hz=profile.rate_hz,
                            gnss=tuple(systems))
    sky = profile.sky
    pdop_x10 = min(round(sky.pdop_mask * 10.0), 0xFFFF) if math.isfinite(sky.pdop_mask) \
        else 0xFFFF
    nav5 = replace(defaults.nav5, pdop_x10=pdop_x10,
                   min_elev_deg=round(sky.elevation_mask_deg))
    return UbxLink(replace(defaults, nav5=nav5))


def pdop_mask_of(pdop_x10: int) -> float:
    """The receiver's PDOP mask (``sky.pdop_mask``) for a u-blox client's CFG-NAV5 pDop /
    CFG-NAVSPG-OUTFIL_PDOP (x 0.1; 0 taken as no mask, as a mask of 0 would allow no fix)."""
    return pdop_x10 / 10.0 if pdop_x10 > 0 else math.inf


def sky_after_nav5(sky: SkyParams, old: Nav5, new: Nav5) -> SkyParams:
    """The receiver's sky settings after a u-blox client changed CFG-NAV5 (or its CFG-NAVSPG
    keys) from ``old`` to ``new``: minElev becomes the elevation mask (within the [-10, 89]
    degrees a profile takes), pDop the PDOP mask (:func:`pdop_mask_of`); what the client left
    alone keeps the profile's value."""
    if new.min_elev_deg != old.min_elev_deg:
        sky = replace(sky, elevation_mask_deg=float(min(max(new.min_elev_deg, -10), 89)))
    if new.pdop_x10 != old.pdop_x10:
        sky = replace(sky, pdop_mask=pdop_mask_of(new.pdop_x10))
    return sky


def tracking_systems(rx: Receiver, profile: Profile, enabled: frozenset[str]) -> Receiver:
    """The receiver tracking the systems of its profile that a u-blox client left enabled
    (CFG-GNSS, CFG-SIGNAL-*_ENA): a system switched off is neither tracked nor listed; one
    switched on that the profile's ephemeris does not hold stays absent.

    rx : the receiver now; profile : its profile at power-on; enabled : the names enabled
    (``UbxSettings.enabled_gnss``: "GPS", "GLONASS", "Galileo", "BeiDou", "QZSS", ...)
    """
    cs = profile.constellations
    systems = cs.systems if cs.enabled else ("GPS",)
    keep = tuple(s for s in systems if sky_systems.system_named(s).name in enabled)
    prof = rx.profile
    return replace(rx, profile=replace(prof, constellations=replace(
        prof.constellations, enabled=True, systems=keep)))


def ubx_format(base: nmea.NmeaFormat, link: UbxLink, rate_hz: float) -> nmea.NmeaFormat | None:
    """The NMEA a u-blox link writes: the profile's sentences the link has on for its port
    (CFG-MSG class F0, CFG-PRT's NMEA output), at their rates (every n-th solution, counted
    on the epoch grid as ``every`` does); None when no sentence is on.

    base : the profile's format; link : the link; rate_hz : solutions per second
    """
    every = link.nmea_every() if link.nmea_enabled() else {}
    sentences = tuple(s for s in base.sentences if s in every)
    if not sentences:
        return None
    slow = tuple(sorted((s, n) for s, n in every.items() if s in sentences and n > 1))
    return replace(base, sentences=sentences, every=slow, fix_rate_hz=rate_hz)


def apply_link_settings(rx: Receiver, settings: mtk.MtkSettings) -> Receiver:
    """The receiver with the link's SBAS and static-navigation settings in its effects.

    Parameters
    ----------
    rx : the receiver
    settings : the command link's settings (``sbas_active``, ``static_nav_mps``)

    Returns
    -------
    rx : a receiver whose profile has ``sbas.enabled`` and ``static_hold`` set accordingly
    """
    prof = rx.profile
    hold = replace(prof.static_hold, enabled=settings.static_nav_mps > 0.0,
                   threshold_mps=settings.static_nav_mps or prof.static_hold.threshold_mps)
    new = replace(prof, sbas=replace(prof.sbas, enabled=settings.sbas_active), static_hold=hold)
    return rx if new == prof else replace(rx, profile=new)


def _format_for(
    base: nmea.NmeaFormat, settings: mtk.MtkSettings, defaults: mtk.MtkSettings, rate_hz: float
) -> nmea.NmeaFormat | None:
    """The output format under the link's sentence rates (None: every sentence switched off)."""
    if settings.rates == defaults.rates:
        return replace(base, fix_rate_hz=rate_hz)
    sentences = mtk.sentence_order(base.sentences, settings)
    if not sentences:
        return None
    enabled = settings.sentence_every()
    every = dict(base.every)
    every.update({s: n for s, n in enabled.items() if s in sentences})
    every = {s: n for s, n in every.items() if s in sentences and n > 1}
    return replace(
        base, sentences=sentences, every=tuple(sorted(every.items())), fix_rate_hz=rate_hz
    )


class LiveReceiver:
    """One receiver of the live loop: its state and random streams, command link, rate, output
    format and device.

    With an MTK command link, ``$PMTK010,001`` goes out at once (before the first epoch); what
    the client writes is answered by :meth:`service_client` between epochs (a reply is queued
    whole, after any epoch already queued, so it never splits an epoch) and applied: restarts
    (no fix until the start's TTFF), fix interval (epochs on multiples of the new interval),
    baud (the device's pacing or port speed), sentence rates; SBAS and the static-navigation
    threshold switch those effects. With a u-blox link its boot notices go out at once, each
    epoch carries the UBX messages the client switched on around the NMEA, and UBX commands
    are answered and applied the same way (:meth:`_service_ubx`). Without a link the client's
    bytes are read and discarded.

    Parameters
    ----------
    rx : the receiver
    device : output device (``write_epoch``, ``read_available``; optional ``fileno``,
        ``set_baud``), never blocking
    fmt : NMEA format
    clock : the simulated clock
    rng : this receiver's random generator
    link : the command link; ``"profile"`` (default) makes the profile's (:func:`make_link`),
        None for none
    receiver_id : the receiver's number (the ``"id"`` of its pose messages)
    antenna_offset_enu_m : (3,) metres, scene ENU, added to every pose (antenna lever arm)
    t_first_unix_s : simulated UTC from which the first epoch is the next on the grid (default:
        now; a fleet gives all its receivers one)

    Attributes
    ----------
    stats : DaemonStats, this receiver's counters
    k : index of the next epoch at ``rate`` (the epoch is at ``k / rate`` simulated UTC)
    """

    def __init__(
        self,
        rx: Receiver,
        device,
        fmt: nmea.NmeaFormat,
        clock: SimClock,
        rng: np.random.Generator,
        link: mtk.MtkLink | UbxLink | None | str = "profile",
        receiver_id: int = 0,
        antenna_offset_enu_m: np.ndarray | None = None,
        t_first_unix_s: float | None = None,
    ) -> None:
        prof = rx.profile
        if isinstance(link, str):
            link = make_link(prof, fmt)
        self.rx, self.prof, self.device, self.clock, self.rng = rx, prof, device, clock, rng
        self.link = link
        self.receiver_id = receiver_id
        self.offset_enu_m = (np.zeros(3) if antenna_offset_enu_m is None
                             else np.asarray(antenna_offset_enu_m, float).reshape(3))
        self.base_fmt = fmt
        self.out_fmt: nmea.NmeaFormat | None = fmt
        self.rate = prof.rate_hz
        self.stats = DaemonStats(link=link)
        self.n_sat = len(rx.ephemeris.prn)
        self.recent_sizes: deque[int] = deque(maxlen=10)  # bytes of the last epochs
        # Whether the line carries the output is looked at every few epochs, from the last
        # epochs' sizes (afresh after a client changes the rate, the baud or the sentences).
        self._line_check_at = self.recent_sizes.maxlen
        self.t_last: float | None = None
        self.applied = link.settings if link is not None else None  # the settings in effect
        t_from = clock.now_unix_s() if t_first_unix_s is None else t_first_unix_s
        self.k = math.ceil(t_from * self.rate - 1e-9)
        # Its row in the batch it was last simulated in, while nothing else touched its state:
        # the next tick of the same batch goes on from the rows as they are.
        self._row: tuple[ReceiverRows, int, Profile] | None = None
        # Power-on at the first epoch's time, as replay does: a run with --start-time starts
        # the same whatever its set-up took (a fleet's receiver as the same receiver alone).
        self.state = initial_state(prof, self.t_next_unix_s, rng, self.n_sat)
        if isinstance(link, UbxLink):
            self.out_fmt = ubx_format(fmt, link, self.rate)
            if boot := link.startup():
                device.write_epoch(boot)
        elif link is not None:
            device.write_epoch(link.startup().encode("ascii"))

    @property
    def state(self) -> ReceiverState:
        """The receiver state after its last epoch."""
        if self._row is not None:
            rows, i, prof = self._row
            self._state = rows.row_state(i, prof)
            self._row = None
        return self._state

    @state.setter
    def state(self, state: ReceiverState) -> None:
        self._state = state
        self._row = None

    def next_k(self, r: float) -> int:
        """Index of the next epoch at rate ``r``: after the last one, not in the past."""
        k_now = math.ceil(self.clock.now_unix_s() * r - 1e-9)
        if self.t_last is None:
            return k_now
        return max(math.floor(self.t_last * r + 1e-6) + 1, k_now)

    @property
    def t_next_unix_s(self) -> float:
        """Simulated UTC of the next epoch, seconds."""
        return self.k / self.rate

    def service_client(self) -> None:
        """Read what the client wrote; with a link answer and apply it."""
        data = self.device.read_available()
        link, prof = self.link, self.prof
        if link is None or self.applied is None or not data:
            return
        if isinstance(link, UbxLink):
            self._service_ubx(link, data)
            return
        for resp in link.feed(data, max(self.recent_sizes, default=0)):
            old = self.applied
            if resp.replies:
                self.device.write_epoch("".join(resp.replies).encode("ascii"))
            if resp.restart is not None:
                self.state = restart(self.state, resp.restart, self.clock.now_unix_s(), prof,
                                     self.rng, self.n_sat)
                log.info("client commanded a %s start", resp.restart)
            new = self.applied = resp.settings
            if new is old:
                continue
            if new.baud != old.baud:
                self._set_baud(new.baud)
            if new.fix_interval_ms != old.fix_interval_ms:
                self.rate = (
                    prof.rate_hz
                    if new.fix_interval_ms == link.defaults.fix_interval_ms
                    else new.rate_hz
                )
                self.k = self.next_k(self.rate)
                log.info("client set the fix interval to %d ms", new.fix_interval_ms)
            if new.rates != old.rates or new.fix_interval_ms != old.fix_interval_ms:
                self.out_fmt = _format_for(self.base_fmt, new, link.defaults, self.rate)
            if (new.baud, new.rates, new.fix_interval_ms) != (old.baud, old.rates,
                                                              old.fix_interval_ms):
                # (recent_sizes is kept: the link's too-fast check of $PMTK220 needs it; by
                # the next check it holds only epochs made after the change)
                self._line_check_at = self.stats.epochs + self.recent_sizes.maxlen
            if (new.sbas_active, new.static_nav_mps) != (old.sbas_active, old.static_nav_mps):
                self.rx = apply_link_settings(self.rx, new)
                log.info("client set SBAS %s, static navigation %.2f m/s",
                         "on" if new.sbas_active else "off", new.static_nav_mps)

    def _set_baud(self, baud: int) -> None:
        """The line's new speed (the device's pacing or the port's), as a client set it."""
        set_baud = getattr(self.device, "set_baud", None)
        if set_baud is not None:
            set_baud(baud)
        log.info("client set the baud rate to %d", baud)

    def _service_ubx(self, link: UbxLink, data: bytes) -> None:
        """Answer a u-blox client and apply what it set: each reply is queued whole, then its
        settings applied (a baud change after the ACK has gone out at the old baud, as the
        module does); CFG-RST restarts the receiver; the navigation rate, the NMEA sentences,
        SBAS, the elevation and PDOP masks (:func:`sky_after_nav5`) and the systems tracked
        (:func:`tracking_systems`) follow the link's settings."""
        for resp in link.feed(data):
            if resp.reply:
                self.device.write_epoch(resp.reply)
            if resp.restart is not None:
                self.state = restart(self.state, resp.restart, self.clock.now_unix_s(),
                                     self.prof, self.rng, self.n_sat)
                log.info("client commanded a %s start (%s)", resp.restart, resp.command)
            old, new = self.applied, resp.settings
            if new is None or new == old:
                continue
            self.applied = new
            if new.baud != old.baud:
                self._set_baud(new.baud)
            if new.nav_period_ms != old.nav_period_ms:
                self.rate = 1000.0 / new.nav_period_ms
                self.k = self.next_k(self.rate)
                log.info("client set the navigation period to %d ms", new.nav_period_ms)
            self.out_fmt = ubx_format(self.base_fmt, link, self.rate)
            self._line_check_at = self.stats.epochs + self.recent_sizes.maxlen
            if new.sbas_enabled != old.sbas_enabled:
                prof = self.rx.profile
                self.rx = replace(self.rx, profile=replace(
                    prof, sbas=replace(prof.sbas, enabled=new.sbas_enabled)))
                log.info("client set SBAS %s", "on" if new.sbas_enabled else "off")
            prof = self.rx.profile
            sky = sky_after_nav5(prof.sky, old.nav5, new.nav5)
            if sky != prof.sky:
                self.rx = replace(self.rx, profile=replace(prof, sky=sky))
                log.info("client set the elevation mask to %g deg and the PDOP mask to %g",
                         sky.elevation_mask_deg, sky.pdop_mask)
            if new.enabled_gnss != old.enabled_gnss:
                self.rx = tracking_systems(self.rx, self.prof, new.enabled_gnss)
                log.info("client set the systems tracked: %s",
                         ", ".join(self.rx.profile.constellations.systems) or "none")

    def sent(self, data: bytes | None, has_fix: bool) -> None:
        """Queue the epoch's NMEA (None: every sentence switched off) and move to the next
        epoch."""
        if data is not None:
            self.device.write_epoch(data)
            self.recent_sizes.append(len(data))
        if self.stats.epochs >= self._line_check_at:  # (every few epochs: a fix lengthens them)
            self._line_check_at = self.stats.epochs + self.recent_sizes.maxlen
            warn_if_line_too_slow(self.recent_sizes, self.rate, getattr(self.device, "baud", None))
        self.t_last = self.t_next_unix_s
        self.stats.epochs += 1
        self.stats.fixes += int(has_fix)
        self.stats.last_fix = has_fix
        self._advance()

    def skip(self) -> None:
        """Leave this epoch out (the loop cannot compute every receiver's: see
        :class:`Thinning`) and move to the next."""
        self.stats.thinned_epochs += 1
        self._advance()

    def _advance(self) -> None:
        self.k += 1
        # Fell behind by more than one period (machine suspended, debugger): skip to now rather
        # than emit a burst of old epochs.
        k_now = math.floor(self.clock.now_unix_s() * self.rate)
        if k_now > self.k:
            self.stats.skipped_epochs += k_now - self.k
            self.k = k_now


_LINE_WARNED: set[tuple[float, int]] = set()  # (rate, baud) already warned of, once a process


def warn_if_line_too_slow(sizes: Sequence[int], rate_hz: float, baud: int | None) -> bool:
    """Warn (once per rate and baud in a process) when the epochs need more than the serial
    line carries: the device then drops the oldest whole epochs to keep its output fresh, and
    a client sees fewer epochs than the rate, as behind a real receiver set to a rate its baud
    cannot carry (MTK's PMTK220 notes: 10 Hz wants 115200 baud or fewer sentences).

    Parameters
    ----------
    sizes : bytes of the last epochs
    rate_hz : epochs per second
    baud : the line's bits per second (8N1: 10 bits a byte); None for a device without a line

    Returns
    -------
    bool : whether the line is too slow
    """
    if baud is None or not sizes:
        return False
    need_baud = 10.0 * rate_hz * sum(sizes) / len(sizes)
    if need_baud <= baud:
        return False
    if (rate_hz, baud) not in _LINE_WARNED:
        _LINE_WARNED.add((rate_hz, baud))
        log.warning(
            "at %g Hz an epoch of ~%d bytes needs %d baud: the %d-baud line carries %.0f %% of "
            "the epochs, the rest are dropped (raise the baud rate, e.g. --baud 115200 or "
            "$PMTK251, lower the rate, or switch sentences off with $PMTK314)",
            rate_hz, round(sum(sizes) / len(sizes)), math.ceil(need_baud), baud,
            100.0 * baud / need_baud)
    return True
