"""The /status document as a typed model: the one definition of its schema.

`Status` (pydantic) says what /status contains, field by field; the OpenAPI document's
`Status` schema is generated from it (`openapi_schema`), translated to OpenAPI 3.0's
dialect (`nullable: true` instead of JSON Schema's `anyOf [.., null]`, no `$ref`s or
titles). `RelayState.snapshot()` still builds the dict itself, by hand, because it runs
on every request of a 1000 req/s client and a model round trip would cost a good
share of that; `tests/api/test_status_model.py` checks that every snapshot validates
against `Status` (strict, no extra keys) and that each field of the model appears.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from relayd.core.geometry import SONAR_COUNT
from relayd.core.vocab import DriveState, Mode


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class Wheels(_Model):
    left: float
    right: float


class Pose(_Model):
    x_mm: float | None
    y_mm: float | None
    theta_deg: float | None


class LastScan(_Model):
    t: float
    age_s: float
    angles: list[float]
    rssi: list[float]
    bearing_deg: float
    rssi_leader_dbm: float
    period_s: float | None


class Link(_Model):
    signal_dbm: float | None
    rssi: float | None
    noise_dbm: float | None
    ccq_pct: float | None
    tx_mbps: float | None
    rx_mbps: float | None
    age_s: float | None


class Health(_Model):
    connected: bool
    age_s: float | None
    errors: Annotated[int, Field(ge=0)]
    reconnects: Annotated[int, Field(ge=0)]
    last_error: str | None


class LinkModel(_Model):
    """The rear-link model (docs/CONTROL.md section 5.1): the limit it sets and why."""

    policy: Literal["fixed", "adaptive"] = Field(
        description="adaptive: threshold_b_dbm is the model's; fixed: the model only advises"
    )
    threshold_b_dbm: float = Field(description="the model's rear limit (in force when adaptive)")
    configured_threshold_b_dbm: float
    bounds_dbm: Annotated[list[float], Field(min_length=2, max_length=2)]
    target_hop_mbps: float
    outage: float
    learning: bool = Field(
        description="enough samples for the model's limit to replace the configured one"
    )
    samples: Annotated[int, Field(ge=0)]
    effective_samples: float
    ok_share: float | None = Field(description="share of recent polls that met target_hop_mbps")
    mu_dbm: float = Field(description="RSSI^b at which the hop meets the target half of the time")
    spread_db: float = Field(description="how gradually P(meets target) rises with RSSI^b (fading)")
    p_ok_now: float | None = Field(description="P(meets target) at the last RSSI^b")
    last_rssi_dbm: float | None
    last_delivered_mbps: float | None
    stale: bool
    refused_stale: Annotated[int, Field(ge=0)]


class Recording(_Model):
    """The recorder (docs/RECORDING.md); None in /status when the daemon has none."""

    enabled: bool
    state: Literal["off", "recording", "stopped", "failed"] = Field(
        description="failed: a write error (e.g. a full disk) ended the recording; the robot keeps working"
    )
    path: str | None = Field(description="the file being written, or the last one")
    files: Annotated[int, Field(ge=0)]
    bytes: Annotated[int, Field(ge=0)]
    events: Annotated[int, Field(ge=0)]
    dropped: Annotated[int, Field(ge=0)]
    error: str | None


class Recovery(_Model):
    """The self-healing state machine (docs/CONTROL.md); None in /status while disabled."""

    enabled: bool
    phase: Literal["idle", "widen", "retrace", "backup", "gave_up"]
    kind: Literal["leader", "rear"] | None = Field(description="which link the episode heals")
    episodes: Annotated[int, Field(ge=0)]
    elapsed_s: float | None = Field(description="seconds into the running episode (whole seconds)")
    distance_m: float | None = Field(description="odometry travel of the running episode")
    max_distance_m: float
    max_time_s: float
    trail_crumbs: Annotated[int, Field(ge=0)]
    last_outcome: str | None = Field(
        description="found, restored, preempted, aborted, gave_up_time or gave_up_distance"
    )


class LeaderFeed(_Model):
    """A relay following a relay: its leader's GET /path, and why it is followed or not."""

    state: Literal["waiting", "up", "stale", "rejected"] = Field(
        description="waiting: no answer yet; up: followed; stale: the leader's pose is older "
        "than control.leader_stale_s (the estimate leads); rejected: the alignment "
        "disagrees with this relay's bearings of the leader (the estimate leads)"
    )
    age_s: float | None = Field(description="since the leader's pose last moved on (s)")
    alignment: str | None = Field(
        description="prior (start poses only), refined (by the bearings), bearings_disagree, "
        "too_far_from_prior; null before a sighting"
    )
    residual_deg: float | None = Field(
        description="the bearings' median absolute residual under the alignment (deg)"
    )
    sightings: int = Field(description="bearings of the leader the alignment uses")


class Trail(_Model):
    """The leader's trail in this relay's odometry frame (relayd/core/trail)."""

    source: Literal["leader_feed", "estimate", "bearing"] = Field(
        description="what the pursuit steers by: the leader relay's own path (its GET /path, "
        "aligned), the estimated trail, or the scan bearing (no trail)"
    )
    leader_xy_m: list[float] | None = Field(
        description="the estimated leader position [x, y] (m, odometry frame); null before a scan"
    )
    leader_sigma_m: float | None = Field(
        description="its 1-sigma radius (m): the covariance's largest eigenvalue, square-rooted"
    )
    points_m: list[list[float]] = Field(
        description="the trail's newest points [x, y] (m), oldest first"
    )
    steer_deg: float | None = Field(
        description="the pursuit target's bearing (robot frame, ccw +); null: not steering by the trail"
    )
    caught_up: bool = Field(description="the relay is at the trail's head (it holds and scans)")
    feed: LeaderFeed | None = Field(
        default=None, description="the leader relay's feed (control.leader_url); null: none"
    )
    detour_m: list[list[float]] | None = Field(
        default=None,
        description="the detour in force round what the sonar map shows in the straight way: "
        "its path [x, y] (m, odometry frame); null: the way is clear (relayd/core/plan)",
    )


class PatternLearned(_Model):
    """The scan antenna's pattern learnt online (scan.learn_pattern, docs/CONTROL.md 10.7)."""

    scans: Annotated[int, Field(ge=0)] = Field(
        description="scans the filter was sure of that entered the learnt table"
    )
    refused: Annotated[int, Field(ge=0)] = Field(
        description="scans offered but not sure enough (sd, or too near a servo limit)"
    )
    coverage_deg: Annotated[float, Field(ge=0)] = Field(
        description="degrees of off-axis angle with at least 3 samples"
    )
    ready: bool = Field(description="the fit matches the learnt pattern (its main lobe is covered)")


class PathPose(_Model):
    t: float = Field(description="the SIP's time (s, the daemon's clock)")
    x_m: float
    y_m: float
    theta_deg: float


class OwnPath(_Model):
    """GET /path: this relay's odometry pose and the path it drove (a relay following it
    follows this path), odometry frame, oldest first."""

    pose: PathPose | None = Field(description="the newest pose; null before the first SIP")
    points: list[Annotated[list[float], Field(min_length=3, max_length=3)]] = Field(
        description="[t, x_m, y_m]: a point each 0.1 m, the newest 600"
    )


class Status(_Model):
    version: str
    robot: str | None = Field(description="name the base reports (ARCOS SYNC2)")
    display_name: str | None = Field(
        description="the operator's name for this robot (config robot.display_name)"
    )
    uptime_s: float
    mode: Mode
    state: DriveState
    reason: str
    bearing_deg: float | None = Field(
        description="leader bearing, robot frame, counter-clockwise positive"
    )
    bearing_sd_deg: float | None = Field(
        description="the bearing's standard deviation from the tracking filter (null: the WCA estimator, or no track)"
    )
    link_bearing_deg: float | None = Field(description="where the link antenna (servo 2) points")
    rssi_leader_dbm: float | None = Field(description="RSSI^l: best RSSI of the last scan")
    rssi_behind_dbm: float | None = Field(description="RSSI^b: RSSI of the node behind")
    situation: Literal[0, 1, 2]
    wheels_mm_s: Wheels
    pose: Pose
    battery_v: float | None
    motors_enabled: bool
    sonar_mm: Annotated[list[int | None], Field(min_length=SONAR_COUNT, max_length=SONAR_COUNT)]
    last_scan: LastScan | None
    scan_count: Annotated[int, Field(ge=0)]
    links: dict[str, Link]
    health: dict[str, Health]
    thresholds: dict[str, float]
    link_model: LinkModel | None
    recording: Recording | None
    recovery: Recovery | None = Field(description="self-healing state machine; null while disabled")
    trail: Trail | None = Field(
        default=None, description="the leader's trail (control.pursuit); null when not wired"
    )
    pattern_learned: PatternLearned | None = Field(
        default=None,
        description="the antenna pattern learnt online (scan.learn_pattern); null: not learning",
    )


_DROP = {"title", "default"}
_RENAME = {"minLength": "minItems", "maxLength": "maxItems"}


def _to_openapi(node: Any, defs: dict[str, Any]) -> Any:
    """One JSON Schema node in OpenAPI 3.0's dialect, with every `$ref` inlined."""
    if isinstance(node, list):
        return [_to_openapi(n, defs) for n in node]
    if not isinstance(node, dict):
        return node
    ref = node.get("$ref")
    if isinstance(ref, str):
        target = defs[ref.rsplit("/", 1)[-1]]
        extra = {k: v for k, v in node.items() if k != "$ref"}
        return _to_openapi({**target, **extra}, defs)
    any_of = node.get("anyOf")
    if isinstance(any_of, list) and {"type": "null"} in any_of:
        rest = [n for n in any_of if n != {"type": "null"}]
        inner = rest[0] if len(rest) == 1 else {"anyOf": rest}
        merged = {**{k: v for k, v in node.items() if k != "anyOf"}, **_to_openapi(inner, defs)}
        merged["nullable"] = True
        return {k: v for k, v in merged.items() if k not in _DROP}
    out: dict[str, Any] = {}
    for key, value in node.items():
        if key in _DROP or key == "$defs":
            continue
        if key == "const":
            out["enum"] = [value]
            continue
        name = str(key)
        if node.get("type") == "array":
            name = _RENAME.get(name, name)
        out[name] = _to_openapi(value, defs)
    if out.get("type") == "object" and "properties" in out:
        out["required"] = list(out["properties"])
    return out


def openapi_schema(model: type[BaseModel] = Status) -> dict[str, Any]:
    """The model's schema for an OpenAPI 3.0 document."""
    schema = model.model_json_schema()
    defs = schema.pop("$defs", {})
    result: dict[str, Any] = _to_openapi(schema, defs)
    return result
