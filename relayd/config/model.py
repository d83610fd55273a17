"""relayd's settings: a pydantic model for every config key and its default.

Every key has the paper's default; unknown keys are errors (a typo such as
`kpp = 2` must not silently leave kp at its default on a robot) and come with a
"did you mean" suggestion. Types are strict: `enabled = "off"`, `enabled = 1` and
`kp = "2.5"` are errors, not conversions; an integer is accepted where a float is
expected (`kp = 2` is natural TOML). Floats must be finite. The models' validators
call the cross-key rules of relayd.config.checks (threshold order, distances), so a
Settings built in code obeys them too. Secrets never live in the TOML: a section
names an environment variable (`password_env`, `token_env`) or a file
(`password_file`, `token_file`) and `resolve_secret` reads it at start-up.
Reading a TOML file into Settings (every problem in one pass, check-config's
warnings) lives in relayd.config.load, writing settings back out as TOML in
relayd.config.tomlwriter, the secrets in relayd.config.secrets (re-exported here).
"""

from __future__ import annotations

import ipaddress
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    field_validator,
    model_validator,
)

from relayd.config.checks import ConfigError as ConfigError
from relayd.config.checks import (
    ap_rules,
    avoidance_rules,
    control_rules,
    leader_url_error,
    pantilt_rules,
    raise_first,
)

# Secrets (where each comes from, reading it) live in relayd.config.secrets; re-exported.
from relayd.config.secrets import MIN_API_TOKEN_CHARS as MIN_API_TOKEN_CHARS
from relayd.config.secrets import SecretRef as SecretRef
from relayd.config.secrets import check_api_token as check_api_token
from relayd.config.secrets import resolve_secret as resolve_secret
from relayd.config.secrets import secret_file_errors as secret_file_errors
from relayd.config.secrets import secret_refs as secret_refs
from relayd.core.scan.pattern import AntennaPattern, PatternError, parse_pattern

BAUD_RATES = (9600, 19200, 38400, 57600, 115200)

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
#: A received signal level: never above 0 dBm at a receiver (a positive value is a sign error).
Dbm = Annotated[float, Field(ge=-120, le=0, allow_inf_nan=False)]


def _list_to_tuple(v: Any) -> Any:
    # TOML has arrays, not tuples: strict mode would refuse every `[a, b, c]`.
    return tuple(v) if isinstance(v, list) else v


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class RobotSettings(_Section):
    #: What operators call this robot on the live page, /status and the fleet view.
    display_name: Annotated[str, Field(min_length=1, max_length=64)] | None = None
    enabled: bool = True
    port: str = "/dev/relay/base"
    baud: Literal[9600, 19200, 38400, 57600, 115200] = 9600
    subclass: Literal["p3at", "p3at-sh"] | None = None
    lost_after_s: PositiveFloat = 0.5


PulseTriple = Annotated[
    tuple[
        Annotated[int, Field(ge=400, le=2600)],
        Annotated[int, Field(ge=400, le=2600)],
        Annotated[int, Field(ge=400, le=2600)],
    ],
    BeforeValidator(_list_to_tuple),
]


def _check_pulses(v: PulseTriple) -> PulseTriple:
    lo, mid, hi = v
    # Decreasing triples are legal: a servo mounted upside down turns the other way.
    if not (lo < mid < hi or lo > mid > hi):
        raise ValueError("pulse widths at -90, 0, +90 degrees must be strictly monotonic")
    return v


class PanTiltSettings(_Section):
    enabled: bool = True
    port: str = "/dev/relay/servo"
    protocol: Literal["maestro", "ssc32"] = "maestro"
    baud: Literal[9600, 19200, 38400, 57600, 115200] = 115200
    scan_channel: Annotated[int, Field(ge=0, le=31)] = 0
    link_channel: Annotated[int, Field(ge=0, le=31)] = 1
    scan_pulse_us: PulseTriple = (1000, 1500, 2000)
    link_pulse_us: PulseTriple = (1000, 1500, 2000)
    limits_deg: Annotated[
        tuple[Annotated[float, Field(ge=-180, le=180)], Annotated[float, Field(ge=-180, le=180)]],
        BeforeValidator(_list_to_tuple),
    ] = (-90.0, 90.0)
    speed_deg_s: Annotated[float, Field(gt=0, le=2000)] = 180.0

    _pulses = field_validator("scan_pulse_us", "link_pulse_us")(_check_pulses)

    @field_validator("limits_deg")
    @classmethod
    def _limits_ordered(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not v[0] < v[1]:
            raise ValueError("limits_deg must be [low, high] with low < high")
        return v

    @model_validator(mode="after")
    def _distinct_channels(self) -> PanTiltSettings:
        raise_first(pantilt_rules(self.model_dump()))
        return self


class WifiSettings(_Section):
    enabled: bool = True
    source: Literal["nl80211", "procfs", "iw"] = "nl80211"
    # The name config/99-relayd.rules gives the Yagi's adapter: a robot set up from
    # docs/DEPLOY.md needs no [wifi] interface line.
    interface: Annotated[str, Field(min_length=1, max_length=15)] = "yagi0"
    procfs_path: str = "/proc/net/wireless"
    sample_hz: Annotated[float, Field(gt=0, le=1000)] = 20.0


class ApSettings(_Section):
    enabled: bool = True
    url: str
    username: str = "ubnt"
    password_env: str | None = None
    password_file: str | None = None
    poll_s: PositiveFloat = 1.0
    timeout_s: PositiveFloat = 2.0
    legacy_tls: bool = False
    #: rear AP only: the MAC of the node behind; None = the strongest station.
    station_mac: str | None = None

    @field_validator("url")
    @classmethod
    def _http(cls, v: str) -> str:
        if not v.startswith(("http://", "https://")):
            raise ValueError("url must start with http:// or https://")
        return v.rstrip("/")

    @model_validator(mode="after")
    def _one_secret_source(self) -> ApSettings:
        raise_first(ap_rules("", self.model_dump()))
        return self


class ApSection(_Section):
    rear: ApSettings | None = None
    front: ApSettings | None = None


class ScanSettings(_Section):
    samples: Annotated[int, Field(ge=3, le=361)] = 25
    width_deg: Annotated[float, Field(gt=0, le=360)] = 180.0
    gamma: PositiveFloat = 10.0
    mode: Literal["step", "continuous"] = "step"
    settle_s: NonNegFloat = 0.05
    #: Bearing estimator: "lobe" (main-lobe fit and tracking filter, docs/CONTROL.md
    #: section 10; the default: it measured best) or "wca" (the paper's weighted centroid).
    estimator: Literal["wca", "lobe"] = "lobe"
    #: "adaptive": narrower around a confident prediction (needs estimator "lobe");
    #: "full": every sweep `width_deg` wide. Unset: "adaptive" with "lobe", "full" with
    #: "wca" (so `estimator = "wca"` alone is the paper's estimator, as it always was).
    window: Literal["full", "adaptive"] = "adaptive"
    #: The scan antenna's measured pattern (a file `relayd calibrate antenna` writes):
    #: with it each scan's bearing is the pattern matched to the scan (docs/CONTROL.md
    #: section 10.6) instead of the main-lobe fit. Needs estimator "lobe".
    pattern_file: str | None = None
    #: Without a pattern file: learn the pattern from scans the tracking filter is sure of
    #: and fit with it once learnt (docs/CONTROL.md section 10.7). Needs estimator "lobe".
    learn_pattern: bool = False

    @field_validator("pattern_file")
    @classmethod
    def _pattern_usable(cls, v: str | None) -> str | None:
        if v is not None:
            load_pattern_file(v)  # a ValueError naming the file and the key in it
        return v

    @model_validator(mode="before")
    @classmethod
    def _window_follows_estimator(cls, data: Any) -> Any:
        if isinstance(data, dict) and "window" not in data and data.get("estimator") == "wca":
            return {**data, "window": "full"}
        return data

    @model_validator(mode="after")
    def _adaptive_needs_tracking(self) -> ScanSettings:
        if self.window == "adaptive" and self.estimator != "lobe":
            raise ValueError(
                'window "adaptive" needs estimator "lobe" (the WCA has no confidence to narrow on)'
            )
        if self.pattern_file is not None and self.estimator != "lobe":
            raise ValueError('pattern_file needs estimator "lobe" (the WCA uses no pattern)')
        if self.learn_pattern and self.estimator != "lobe":
            raise ValueError('learn_pattern needs estimator "lobe" (the WCA uses no pattern)')
        if self.learn_pattern and self.pattern_file is not None:
            raise ValueError("learn_pattern: a pattern_file is set; the measured pattern is used")
        return self


def load_pattern_file(path: str) -> AntennaPattern:
    """The antenna pattern in the file at `path`; ValueError naming the file and what is wrong."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        return parse_pattern(text)
    except PatternError as exc:
        raise ValueError(f"{path}: {exc}") from None


class ControlSettings(_Section):
    mode: Literal["follow", "hold", "manual"] = "follow"
    threshold_l_dbm: Dbm = -30.0
    threshold_b_dbm: Dbm = -60.0
    hysteresis_db: NonNegFloat = 2.0
    rear_link: Literal["require", "ignore"] = "require"
    kp: NonNegFloat = 1.0
    kd: NonNegFloat = 0.3
    w1: NonNegFloat = 10.0
    w2: Annotated[float, Field(allow_inf_nan=False)] = 150.0
    v_max_mm_s: Annotated[float, Field(gt=0, le=1500)] = 400.0
    threshold_o_m: PositiveFloat = 0.8
    stop_distance_m: NonNegFloat = 0.3
    detect_range_m: PositiveFloat = 3.0
    gamma_o_m: PositiveFloat = 1.0
    alpha_db: NonNegFloat = 30.0
    beta_per_m: NonNegFloat = 1.0
    lost_rssi_dbm: Dbm = -85.0
    manual_deadman_s: PositiveFloat = 0.5
    #: RSSI^b older than this many rear-AP polls is stale (our choice, docs/CONTROL.md 6: 3 polls).
    rear_stale_polls: Annotated[int, Field(ge=1, le=100)] = 3
    #: "fixed": stop at threshold_b_dbm everywhere; "adaptive": learn the rear hop's
    #: RSSI-to-rate relation and set the limit from it (docs/CONTROL.md section 5.1).
    link_policy: Literal["fixed", "adaptive"] = "fixed"
    #: The throughput the hop behind must carry (Mbit/s, after MAC overhead).
    target_hop_mbps: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 10.0
    #: Accepted probability that the hop delivers less than target_hop_mbps where the relay stops.
    outage_probability: Annotated[float, Field(gt=0, lt=0.5, allow_inf_nan=False)] = 0.1
    #: The adaptive limit stays within [threshold_b_min_dbm, threshold_b_max_dbm].
    threshold_b_min_dbm: Dbm = -80.0
    threshold_b_max_dbm: Dbm = -50.0
    #: Share of the PHY rate that reaches the application (802.11 MAC overhead).
    mac_efficiency: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = 0.5
    #: The model forgets a sample's weight by half over this many rear polls.
    link_half_life_polls: Annotated[float, Field(ge=5, le=10000, allow_inf_nan=False)] = 20.0
    #: The escape when forward motion is blocked (docs/AVOIDANCE.md); false leaves the
    #: paper's obstacle rule alone (for experiments and benchmarks, not for a robot).
    escape: bool = True
    #: Keep following past "leader_near" while the leader is well inside the front sonars'
    #: fan and they put everything in it at least this far (m) (docs/CONTROL.md section
    #: 5.3); 0 = off, the paper's rule alone. When on: above threshold_o_m, at most 5 m.
    leader_gap_max_m: NonNegFloat = 0.0
    #: A lost leader last seen beyond the scan servo's reach (behind the relay) is turned
    #: toward in place, at most one full turn (docs/CONTROL.md section 6.1); false: stand.
    search_turn: bool = True
    #: ... at this rate (deg/s): a full-range sweep while turning must still fit a lobe.
    search_turn_deg_s: Annotated[float, Field(ge=5, le=90, allow_inf_nan=False)] = 25.0
    #: (relayd/core/trail) "trail" steers along the leader's estimated trail (pure
    #: pursuit), "bearing" at the scan bearing as the paper's relays did.
    pursuit: Literal["trail", "bearing"] = "bearing"
    #: (relayd/core/plan) Go round what the sonar map shows in the straight way to the
    #: leader (a wall its signal comes through, the arm of a U) on a planned path; false
    #: (the default until it wins everywhere, docs/CONTROL.md 7.2): the pursuit's straight
    #: way and the escape alone, as the paper's relays drove.
    detour: bool = False
    #: Steer off a wall beside the robot nearer than this to its 90 deg sonar (m), in
    #: proportion; 0: the paper's law alone (relayd/core/control/steer.py keep_off_sides).
    side_keep_m: Annotated[float, Field(ge=0, le=1.5, allow_inf_nan=False)] = 0.35
    #: Steer no further into a wall whose echoes are within this of the side sonars than
    #: along it (m); 0: the paper's law alone (relayd/core/control/steer.py slide_along_wall).
    wall_slide_m: Annotated[float, Field(ge=0, le=3.0, allow_inf_nan=False)] = 1.5
    #: The paper's situation 1 slows by the nearest forward echo, to a stop at
    #: stop_distance_m; an echo beside the robot's path (a corridor's wall seen by the 50
    #: deg sonars) slows it no lower than this share of its speed, while what may lie in
    #: its path still slows it to a stop. 0: the paper's law (relayd/core/control/steer.py).
    beside_speed_floor: Annotated[float, Field(ge=0, le=1.0, allow_inf_nan=False)] = 0.3
    #: The path-loss model the leader's range is estimated with (`relayd calibrate` fits
    #: them): RSSI = L0 - 10 n log10(d) + N(0, sigma).
    pathloss_l0_dbm: Dbm = -15.0
    pathloss_exponent: Annotated[float, Field(ge=1.0, le=6.0, allow_inf_nan=False)] = 2.0
    pathloss_sigma_db: Annotated[float, Field(gt=0, le=20, allow_inf_nan=False)] = 6.0
    #: A relay following a relay: the leader relay's API (its GET /path is followed with
    #: pursuit "trail"; docs/CONTROL.md 7.1). Unset: the leader is estimated from the scans.
    leader_url: str | None = None
    #: Where the leader's odometry started, in this relay's odometry frame (x_m, y_m,
    #: heading_deg): the alignment's prior (the fleet config's origins give it).
    leader_origin: (
        Annotated[
            tuple[Finite, Finite, Annotated[float, Field(ge=-360, le=360)]],
            BeforeValidator(_list_to_tuple),
        ]
        | None
    ) = None
    #: GET /path every this many s; a leader pose older than leader_stale_s is not followed.
    leader_poll_s: Annotated[float, Field(ge=0.1, le=10, allow_inf_nan=False)] = 0.5
    leader_stale_s: Annotated[float, Field(ge=0.5, le=60, allow_inf_nan=False)] = 2.0

    @field_validator("leader_url")
    @classmethod
    def _leader_url(cls, v: str | None) -> str | None:
        if v is None:
            return None
        v = v.strip().rstrip("/")
        error = leader_url_error(v)
        if error is not None:
            raise ValueError(error)
        return v

    @model_validator(mode="after")
    def _cross_key_rules(self) -> ControlSettings:
        raise_first(control_rules(self.model_dump()))
        return self


class AvoidanceSettings(_Section):
    """The obstacle escape's limits and turn rates (docs/AVOIDANCE.md); the rest of its
    geometry is fitted to the P3-AT's sonar ring and stays in code (AvoidParams)."""

    #: An escape that has not got past within this time, path or total turn holds
    #: with reason "blocked" (a dead end is reported, never driven into).
    max_escape_s: Annotated[float, Field(gt=0, le=3600)] = 300.0
    max_escape_m: Annotated[float, Field(gt=0, le=500)] = 40.0
    max_turn_deg: Annotated[float, Field(gt=0, le=36000)] = 1080.0
    #: ... or that has taken the robot this far from where it last took over from the
    #: paper's law (the doorway room's far corner is 5.2 m from its door wall): what needs
    #: more is going round a building, away from the leader, not an obstacle.
    max_stray_m: Annotated[float, Field(gt=0, le=100)] = 6.0
    #: A "blocked" escape starts afresh after this wait (s), twice as long at each block
    #: of the same run of escapes, up to blocked_retry_max_s; 0: it holds until the
    #: leader is ahead with its way open, or the operator (as before).
    blocked_retry_s: Annotated[float, Field(ge=0, le=600)] = 10.0
    blocked_retry_max_s: Annotated[float, Field(ge=0, le=3600)] = 80.0
    #: A turn in place the guard refuses with no room behind, or for a wall along a side:
    #: creep on along an arc away from that side until the corners have room (an ALIGN
    #: that cannot, the way ahead open: straight on); false: back off along the wall, go
    #: round, or hold (as before).
    unpin: bool = True
    #: An escape's first move, when the leader is at least this far off the nose (deg)
    #: and its direction open: turn onto it (a jamb beside the way, not between); 0: go
    #: round what is near, as before (only a leader 60 deg or more off is turned onto).
    align_open_deg: Annotated[float, Field(ge=0, le=60)] = 15.0
    #: A hit by an echo beside the way (the +-10 and +-30 deg sonars see the way ahead
    #: open): the escape starts with its turn (backing off at most the unjam's 0.3 m, or
    #: creeping off a wall along the side) instead of backing off 1.2 m first; false: back
    #: off as for any hit (as before).
    beside_turn: bool = True
    #: Turns in place during the escape.
    turn_rate_deg_s: Annotated[float, Field(gt=0, le=100)] = 20.0
    #: No turn in place is ever commanded slower than this (a rate the tyres execute).
    min_turn_deg_s: Annotated[float, Field(ge=1, le=100)] = 8.0
    #: The door passage (relayd/core/avoid/door.py): through a gap at least the robot's
    #: width plus door_margin_m, slowly and in its middle, instead of slowing to a stop in
    #: it and going round. False: the paper's law and the escape alone.
    door_pass: bool = False
    door_margin_m: Annotated[float, Field(ge=0.05, le=1.0)] = 0.2
    door_speed_mm_s: Annotated[float, Field(ge=20, le=400)] = 120.0
    #: The escape leaves for the leader once the lane toward it (the robot's width plus
    #: leave_lane_margin_m each side) is free of echoes for leave_clear_m, rather than once every
    #: sonar near the leader's bearing sees that far (docs/AVOIDANCE.md). False: as before.
    leave_by_lane: bool = False
    leave_lane_margin_m: Annotated[float, Field(ge=0.0, le=0.5)] = 0.1
    #: A lane change is past its obstacle once the obstacle side sees this much beyond
    #: the nearest it came abeam (docs/AVOIDANCE.md); 0: only beyond 1.2 m, as before.
    lane_pass_margin_m: Annotated[float, Field(ge=0.0, le=1.2)] = 0.5
    #: A stop for a lost leader keeps the escape's episode (the side it goes round on, its
    #: hit point), so it goes on round what it was going round; false: it starts afresh.
    keep_episode_when_lost: bool = True
    #: The leader lost mid-manoeuvre: the escape goes on round this long (s) toward where
    #: the scans last put it, while the rear link allows; 0: the loss stops it.
    lost_manoeuvre_s: Annotated[float, Field(ge=0, le=60)] = 5.0

    @model_validator(mode="after")
    def _cross_key_rules(self) -> AvoidanceSettings:
        raise_first(avoidance_rules(self.model_dump()))
        return self


class RecoverySettings(_Section):
    """Self-healing when a link breaks (docs/CONTROL.md section 9); off: today's behaviour."""

    enabled: bool = False
    #: An episode gives up (wheels zero, reason leader_lost / rear_lost) after this much travel ...
    max_distance_m: Annotated[float, Field(gt=0, le=100, allow_inf_nan=False)] = 8.0
    #: ... or this long.
    max_time_s: Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False)] = 60.0
    #: Reverse speed along the trail when the leader is lost / the link behind breaks.
    retrace_speed_mm_s: Annotated[float, Field(gt=0, le=1500, allow_inf_nan=False)] = 200.0
    backup_speed_mm_s: Annotated[float, Field(gt=0, le=1500, allow_inf_nan=False)] = 150.0
    #: Full-range scans, wheels at zero, before retracing.
    widen_scans: Annotated[int, Field(ge=0, le=20)] = 1
    #: Breadcrumbs: one every this much travel, the newest trail_len kept.
    crumb_spacing_m: Annotated[float, Field(ge=0.05, le=5, allow_inf_nan=False)] = 0.25
    trail_len: Annotated[int, Field(ge=2, le=10000)] = 200
    #: A crumb counts as reached this close.
    reach_m: Annotated[float, Field(ge=0.05, le=5, allow_inf_nan=False)] = 0.3
    #: Wheel-speed difference per degree the crumb lies off the rear axis.
    turn_gain_mm_s_deg: Annotated[float, Field(ge=0, le=50, allow_inf_nan=False)] = 3.0


class ApiSettings(_Section):
    enabled: bool = True
    #: an IP address (IPv4 or IPv6), not a host name: resolving a name at boot can fail or change
    bind: str = "0.0.0.0"
    port: Annotated[int, Field(ge=0, le=65535)] = 8080
    token_env: str | None = "RELAYD_API_TOKEN"
    token_file: str | None = None
    #: PEM certificate (chain) and private key: both set, the API serves HTTPS only.
    tls_cert: str | None = None
    tls_key: str | None = None
    #: Host names (beyond IP addresses and localhost) the Host and Origin headers may
    #: carry, e.g. ["relay1.local"]: any other name is refused, against DNS rebinding.
    allowed_hosts: list[Annotated[str, Field(min_length=1, max_length=253)]] = []

    @model_validator(mode="after")
    def _tls_pair(self) -> ApiSettings:
        if (self.tls_cert is None) != (self.tls_key is None):
            raise ValueError("set both tls_cert and tls_key, or neither")
        return self

    @model_validator(mode="before")
    @classmethod
    def _one_token_source(cls, data: Any) -> Any:
        # token_env has a default; naming a token_file replaces it unless both were written.
        if isinstance(data, dict) and data.get("token_file") is not None:
            if data.get("token_env") is not None:
                raise ValueError("set at most one of token_env or token_file")
            data = {**data, "token_env": None}
        return data

    @field_validator("bind")
    @classmethod
    def _ip_address(cls, v: str) -> str:
        try:
            ipaddress.ip_address(v)
        except ValueError:
            raise ValueError(
                f"{v!r} is not an IP address (e.g. 0.0.0.0, 127.0.0.1 or ::)"
            ) from None
        return v


class LogSettings(_Section):
    level: Literal["debug", "info", "warning", "error"] = "info"
    format: Literal["json", "console"] = "json"


class RecordSettings(_Section):
    """Recording every bus event and action to MCAP files (docs/RECORDING.md)."""

    enabled: bool = False
    #: A directory (one file per run, `relayd-<UTC time>.mcap`) or a file ending in `.mcap`.
    path: Annotated[str, Field(min_length=1)] = "/var/lib/relayd/recordings"
    #: A file this big is finished (summary written) and the next part begun.
    max_file_mb: Annotated[float, Field(gt=0, le=1_000_000, allow_inf_nan=False)] = 100.0
    #: The oldest recordings are deleted to keep the total under this.
    max_total_mb: Annotated[float, Field(gt=0, allow_inf_nan=False)] = 2000.0

    @model_validator(mode="after")
    def _total_holds_a_file(self) -> RecordSettings:
        if self.max_total_mb < self.max_file_mb:
            raise ValueError("max_total_mb must be at least max_file_mb")
        return self


class FoxgloveSettings(_Section):
    """The live Foxglove WebSocket server: the recorder's channels, as they happen (docs/RECORDING.md)."""

    enabled: bool = False
    #: Loopback by default: the Foxglove protocol has no authentication, and a viewer
    #: streaming every channel over the relay's own Wi-Fi competes with the link the robot
    #: is there to carry. Reach it through `ssh -L`, or bind 0.0.0.0 on purpose.
    bind: str = "127.0.0.1"
    #: 8765 is what the Foxglove app offers by default for a WebSocket connection.
    port: Annotated[int, Field(ge=0, le=65535)] = 8765

    @field_validator("bind")
    @classmethod
    def _ip_address(cls, v: str) -> str:
        return ApiSettings._ip_address(v)


class Settings(_Section):
    robot: RobotSettings = RobotSettings()
    pantilt: PanTiltSettings = PanTiltSettings()
    wifi: WifiSettings = WifiSettings()
    ap: ApSection = ApSection()
    scan: ScanSettings = ScanSettings()
    control: ControlSettings = ControlSettings()
    avoidance: AvoidanceSettings = AvoidanceSettings()
    recovery: RecoverySettings = RecoverySettings()
    api: ApiSettings = ApiSettings()
    log: LogSettings = LogSettings()
    record: RecordSettings = RecordSettings()
    foxglove: FoxgloveSettings = FoxgloveSettings()
