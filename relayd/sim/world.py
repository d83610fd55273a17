"""The simulated world: relay bodies, sonar beams, collisions, timed doors, the radio chain.

The leader (and a carried command center) walk a relayd.sim.leader_script.LeaderScript;
the world asks it where they are at each `advance`.

Pure and deterministic for a seed: no asyncio, no clock. The runner owns time and the
fake devices; it tells the world the current time (`advance`), the true pose of every
relay (read from the FakeRobots) and where each relay's servos point, and asks it for
sonar ranges (the FakeRobot's `sonar_fn`), whether a motion step is allowed (its
`motion_guard`), the RSSI the Yagi hears, and the per-hop link budget.

Nodes of the chain, front to back: node 0 is the leader (end user), nodes 1..N are the
relays (relay 1 follows the leader, relay k follows relay k-1), node N+1 is the
command center. Hop k joins node k and node k+1.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from relayd.core.geometry import ROBOT_LENGTH_M, ROBOT_RADIUS_M, ROBOT_WIDTH_M, wrap_deg
from relayd.sim.antennas import pattern_gain
from relayd.sim.geometry import (
    Point,
    Polygon,
    Segment,
    footprint,
    polygon_hits_circle,
    polygon_hits_segment,
    polygons_overlap,
)
from relayd.sim.leader_script import LeaderScript
from relayd.sim.radio import (
    MAC_EFFICIENCY,
    Hop,
    LinkBudget,
    Radio,
    patch_gain_db,
    phy_rate_mbps,
    yagi_gain_db,
)
from relayd.sim.scenario import Scenario
from relayd.sim.sonar import Body, SonarReadings, SonarScene
from relayd.sim.spatial import GridIndex

#: P3-AT body (docs/PROTOCOLS.md 1.11, from ARIA's p3at.p: RobotLength 626 mm, RobotWidth 505 mm).
#: The P3-AT footprint's circumradius: no part of the body is farther from its centre.
#: Slack of the collision check's bounding-box pre-test (far above float rounding).
BODY_SLACK_M = 1e-6
#: How close to a doorway a robot holds a timed door open (see World._blocked).
DOOR_CLEAR_M = 0.6
#: A contact episode ends once the footprint is this far from everything again.
CONTACT_CLEAR_M = 0.02
#: From this many static wall pieces on (a building's map), the world indexes them
#: spatially (relayd/sim/spatial.py); below it a scan of the list is as fast.
INDEX_MIN_SEGMENTS = 256


def _point_segment_m(px: float, py: float, s: Segment) -> float:
    ex, ey = s.x2 - s.x1, s.y2 - s.y1
    n2 = ex * ex + ey * ey
    u = 0.0 if n2 == 0 else max(0.0, min(1.0, ((px - s.x1) * ex + (py - s.y1) * ey) / n2))
    return math.hypot(px - (s.x1 + u * ex), py - (s.y1 + u * ey))


@dataclass(slots=True)
class RelayBody:
    """What the world knows of one relay robot: its true pose and servo pointing."""

    name: str
    x_m: float
    y_m: float
    theta_deg: float
    scan_deg: float = 0.0
    link_deg: float = 0.0
    collisions: int = 0
    in_contact: bool = False
    rejected_steps: int = 0

    @property
    def pos(self) -> Point:
        return self.x_m, self.y_m

    def polygon(self) -> Polygon:
        return footprint(self.x_m, self.y_m, self.theta_deg, ROBOT_LENGTH_M, ROBOT_WIDTH_M)


class World:
    """One scenario's world with `scenario.relays` relays."""

    def __init__(self, scenario: Scenario, seed: int = 0) -> None:
        self.scenario = scenario
        self.seed = seed
        self.walls: list[Segment] = scenario.wall_segments()
        self.boxes = scenario.box_shapes()
        self._static: list[Segment] = scenario.static_segments()
        # Timed world events (a door): (appear_s, disappear_s, outline), and which are present.
        self.timed = scenario.timed_obstacles()
        self.timed_present = [False] * len(self.timed)
        self.obstacles: list[Segment] = list(self._static)
        # A map's scan points (x, y, radius): sonar-visible and solid, radio-transparent
        # (they lie on the walls the map's lines already draw, or are furniture).
        self.points: list[tuple[float, float, float]] = [
            (x, y, scenario.point_radius_m) for x, y in scenario.points
        ]
        self._point_index = (
            GridIndex([(x - r, y - r, x + r, y + r) for x, y, r in self.points])
            if self.points
            else None
        )
        self._static_index = (
            GridIndex([s.bbox() for s in self._static])
            if len(self._static) >= INDEX_MIN_SEGMENTS
            else None
        )
        # Boxes attenuate too (a crate or a car is in the way of the radio path); the radio
        # checks every material, timed ones included.
        self.radio = Radio(
            scenario.radio_params(), self._static + [s for *_, o in self.timed for s in o], seed
        )
        self.radio.walls = tuple(self.obstacles)
        # Each relay's scan antenna: None is the simulator's own Yagi (`yagi_gain_db` with
        # the radio's floor, as always); a name is one of relayd/sim/antennas.py's family.
        self._scan_gain: list[Callable[[float], float] | None] = [
            None if (name := scenario.relay_pattern(i)) is None else pattern_gain(name)
            for i in range(scenario.relays)
        ]
        self._dominant = self.radio.params.model == "dominant-path"
        lead = scenario.leader
        self.leader_script = LeaderScript(
            [(w.x, w.y, w.pause_s) for w in lead.waypoints],
            lead.speed_m_s,
            lead.start_s,
            [(c.at_s, c.speed_m_s) for c in lead.speed_profile],
        )
        cc = scenario.command_center
        self.cc_script: LeaderScript | None = None
        if cc.waypoints:
            self.cc_script = LeaderScript(
                [(cc.x, cc.y, 0.0)] + [(w.x, w.y, w.pause_s) for w in cc.waypoints],
                cc.speed_m_s,
                cc.start_s,
            )
        self.leader_kind = lead.kind
        self.leader_radius_m = lead.radius_m
        self.cc: Point = (scenario.command_center.x, scenario.command_center.y)
        self.relays = [
            RelayBody(r.name, r.x, r.y, r.theta_deg) for r in scenario.relay[: scenario.relays]
        ]
        self._sonar_rng = random.Random(seed ^ 0x50AA)
        self.t = 0.0
        self.leader = self.leader_script.pose(0.0)
        self._sonar_cfg = scenario.sonar
        self._apply_timed(0.0)

    # --- time and poses -------------------------------------------------------------
    def advance(self, t: float) -> None:
        """Move the scripted leader (and a carried command center) to time t (clock seconds
        since the run started), and apply the timed world events due by then."""
        self.t = t
        self.leader = self.leader_script.pose(t)
        if self.cc_script is not None:
            p = self.cc_script.pose(t)
            self.cc = (p.x_m, p.y_m)
        self._apply_timed(t)

    def _apply_timed(self, t: float) -> None:
        """Timed obstacles appear and disappear on time, except that one never appears on top
        of a body: a door waits until nobody stands in the doorway (a person closing it would)."""
        changed = False
        for k, (on_s, off_s, outline) in enumerate(self.timed):
            want = on_s <= t and (off_s is None or t < off_s)
            if want == self.timed_present[k]:
                continue
            if want and self._blocked(outline):
                continue
            self.timed_present[k] = want
            changed = True
        if changed:
            self.obstacles = list(self._static)
            for k, (_, _, outline) in enumerate(self.timed):
                if self.timed_present[k]:
                    self.obstacles.extend(outline)
            self.radio.walls = tuple(self.obstacles)

    def _blocked(self, outline: tuple[Segment, ...]) -> bool:
        # A person does not swing a door shut into a robot about to pass it: a robot's
        # footprint within DOOR_CLEAR_M of the doorway holds the door open (at 0.3 m/s that
        # is two seconds, more than the sonar's stop distance and a stop). Without it a door
        # could appear 0.1 m ahead of a moving relay, a contact no controller can avoid.
        margin = 2 * DOOR_CLEAR_M
        for r in self.relays:
            poly = footprint(
                r.x_m, r.y_m, r.theta_deg, ROBOT_LENGTH_M + margin, ROBOT_WIDTH_M + margin
            )
            if any(polygon_hits_segment(poly, s) for s in outline):
                return True
        lx, ly, rad = self.leader.x_m, self.leader.y_m, self.leader_radius_m + 2 * CONTACT_CLEAR_M
        return any(_point_segment_m(lx, ly, s) < rad for s in outline)

    def set_pose(self, i: int, x_mm: float, y_mm: float, theta_deg: float) -> None:
        r = self.relays[i]
        r.x_m, r.y_m, r.theta_deg = x_mm / 1000.0, y_mm / 1000.0, theta_deg

    def set_servos(self, i: int, scan_deg: float, link_deg: float) -> None:
        r = self.relays[i]
        r.scan_deg, r.link_deg = scan_deg, link_deg

    def node_pos(self, k: int) -> Point:
        """Position of chain node k (0 leader, 1..N relays, N+1 command center)."""
        if k == 0:
            return self.leader.x_m, self.leader.y_m
        if k <= len(self.relays):
            return self.relays[k - 1].pos
        return self.cc

    # --- what is near ----------------------------------------------------------------
    def obstacles_near(self, x0: float, y0: float, x1: float, y1: float) -> list[Segment]:
        """The obstacles that may meet the box, in `obstacles` order (all of them without an
        index; callers still test each one exactly)."""
        if self._static_index is None:
            return self.obstacles
        static = self._static
        out = [static[k] for k in self._static_index.query(x0, y0, x1, y1)]
        out.extend(self.obstacles[len(static) :])  # the timed obstacles present now
        return out

    def points_near(
        self, x0: float, y0: float, x1: float, y1: float
    ) -> list[tuple[float, float, float]]:
        """The map points (x, y, radius) that may meet the box."""
        if self._point_index is None:
            return []
        pts = self.points
        return [pts[k] for k in self._point_index.query(x0, y0, x1, y1)]

    # --- bodies ---------------------------------------------------------------------
    def leader_polygon(self) -> Polygon | None:
        if self.leader_kind != "robot":
            return None
        return footprint(
            self.leader.x_m, self.leader.y_m, self.leader.heading_deg, ROBOT_LENGTH_M, ROBOT_WIDTH_M
        )

    def _collides(self, i: int, poly: Polygon) -> bool:
        xs = [p[0] for p in poly]
        ys = [p[1] for p in poly]
        x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
        for s in self.obstacles_near(x0, y0, x1, y1):
            if (
                max(s.x1, s.x2) < x0
                or min(s.x1, s.x2) > x1
                or max(s.y1, s.y2) < y0
                or min(s.y1, s.y2) > y1
            ):
                continue
            if polygon_hits_segment(poly, s):
                return True
        if self.points:
            pr = self.scenario.point_radius_m
            for px, py, r in self.points_near(x0 - pr, y0 - pr, x1 + pr, y1 + pr):
                if polygon_hits_circle(poly, px, py, r):
                    return True
        # A body whose bounding disc's box misses this footprint's box cannot touch it:
        # skipped before its footprint is even made (BODY_SLACK_M: far above rounding).
        x0, x1, y0, y1 = x0 - BODY_SLACK_M, x1 + BODY_SLACK_M, y0 - BODY_SLACK_M, y1 + BODY_SLACK_M
        lx, ly = self.leader.x_m, self.leader.y_m
        lr = ROBOT_RADIUS_M if self.leader_kind == "robot" else self.leader_radius_m
        if not (lx + lr < x0 or lx - lr > x1 or ly + lr < y0 or ly - lr > y1):
            lp = self.leader_polygon()
            if lp is not None:
                if polygons_overlap(poly, lp):
                    return True
            elif polygon_hits_circle(poly, lx, ly, self.leader_radius_m):
                return True
        for j, other in enumerate(self.relays):
            ox, oy = other.x_m, other.y_m
            if (
                j == i
                or ox + ROBOT_RADIUS_M < x0
                or ox - ROBOT_RADIUS_M > x1
                or oy + ROBOT_RADIUS_M < y0
                or oy - ROBOT_RADIUS_M > y1
            ):
                continue
            if polygons_overlap(poly, other.polygon()):
                return True
        return False

    def motion_ok(
        self,
        i: int,
        new_x_mm: float,
        new_y_mm: float,
        new_theta_deg: float,
        old: tuple[float, float, float] | None = None,
    ) -> bool:
        """The motion guard of relay i: False if the step from `old` (mm, mm, deg; default
        the last known pose) to the new pose makes the footprint touch anything.

        A contact is counted once per episode: pushing on against a wall, creeping up to
        it, or turning in place while touching it, is the same collision; the episode ends
        when the robot is CONTACT_CLEAR_M clear of everything again.
        """
        r = self.relays[i]
        if old is None:
            old = (r.x_m * 1000.0, r.y_m * 1000.0, r.theta_deg)
        poly = footprint(
            new_x_mm / 1000.0, new_y_mm / 1000.0, new_theta_deg, ROBOT_LENGTH_M, ROBOT_WIDTH_M
        )
        if not self._collides(i, poly):
            if r.in_contact and not self._collides(
                i,
                footprint(
                    new_x_mm / 1000.0,
                    new_y_mm / 1000.0,
                    new_theta_deg,
                    ROBOT_LENGTH_M + 2 * CONTACT_CLEAR_M,
                    ROBOT_WIDTH_M + 2 * CONTACT_CLEAR_M,
                ),
            ):
                r.in_contact = False
            return True
        if not r.in_contact:
            r.collisions += 1
            r.in_contact = True
        old_poly = footprint(
            old[0] / 1000.0, old[1] / 1000.0, old[2], ROBOT_LENGTH_M, ROBOT_WIDTH_M
        )
        if self._collides(i, old_poly):
            # Already touching (something moved into us): let the robot move so it can get free.
            return True
        r.rejected_steps += 1
        return False

    # --- sensors --------------------------------------------------------------------
    def sonar_scene(self) -> SonarScene:
        """What the sonars could hear now, as plain values (relayd.sim.sonar.SonarScene)."""
        lead = self.leader
        robot = self.leader_kind == "robot"
        return SonarScene(
            self.obstacles_near,
            self.points_near if self.points else None,
            self.scenario.point_radius_m,
            lead.x_m,
            lead.y_m,
            self.leader_radius_m,
            Body(lead.x_m, lead.y_m, lead.heading_deg) if robot else None,
            tuple(Body(r.x_m, r.y_m, r.theta_deg) for r in self.relays),
        )

    def sonar_mm(self, i: int, x_mm: float, y_mm: float, theta_deg: float) -> list[int]:
        """The 16 sonar ranges of relay i at that pose, as a P3-AT reports them.

        One range per sonar: the nearest surface inside its beam (+-beam_deg/2 about the
        transducer's heading, exact, not sampled by rays), measured from the transducer
        face, clipped to [min_range_m, max_range_m]; max range when nothing echoes.
        Gaussian noise only when the scenario sets `sonar.noise_mm` (default 0): noise
        would break the exact mirror symmetry that a real sonar ring shows, and which
        the controller must cope with.
        """
        ring = self._ring(i, x_mm, y_mm, theta_deg)
        return [ring[k] for k in range(len(ring))]

    def sonar_ranges(self, i: int, x_mm: float, y_mm: float, theta_deg: float) -> Sequence[int]:
        """`sonar_mm`, each range computed when it is first read: a P3-AT SIP carries 8 of
        the 16, so the FakeRobot reads half. With sonar noise all 16 are computed at once,
        so the noise draws come in sonar order whichever are read (the same run)."""
        ring = self._ring(i, x_mm, y_mm, theta_deg)
        return ring if self._sonar_cfg.noise_mm <= 0 else [ring[k] for k in range(len(ring))]

    def _ring(self, i: int, x_mm: float, y_mm: float, theta_deg: float) -> SonarReadings:
        scene = self.sonar_scene()
        return SonarReadings(
            scene, i, x_mm, y_mm, theta_deg, cfg=self._sonar_cfg, rng=self._sonar_rng
        )

    def yagi_rssi_dbm(self, i: int, scan_deg: float | None = None) -> float:
        """What relay i's Yagi hears from its leader's transmitter with the scan servo at
        `scan_deg` (default: where the world last saw it)."""
        r = self.relays[i]
        ang = r.scan_deg if scan_deg is None else scan_deg
        lx, ly = self.node_pos(i)  # relay i is node i+1; its leader is node i
        if self._dominant:
            # The Yagi hears the way the dominant path arrives (a doorway, a corner).
            bearing_world = self.radio.arrival_deg(r.pos, (lx, ly))
        else:
            bearing_world = math.degrees(math.atan2(ly - r.y_m, lx - r.x_m))
        off = wrap_deg(bearing_world - (r.theta_deg + ang))
        own = self._scan_gain[i] if i < len(self._scan_gain) else None
        gain = yagi_gain_db(off, self.radio.params.yagi_floor_db) if own is None else own(off)
        return self.radio.sample_dbm(r.pos, (lx, ly), gain)

    def true_bearing_deg(self, i: int) -> float:
        """The leader's bearing in relay i's frame (what a perfect estimator would say)."""
        r = self.relays[i]
        lx, ly = self.node_pos(i)
        return wrap_deg(math.degrees(math.atan2(ly - r.y_m, lx - r.x_m)) - r.theta_deg)

    def gap_m(self, i: int) -> float:
        """Distance from relay i to its leader (centre to centre)."""
        r = self.relays[i]
        lx, ly = self.node_pos(i)
        return math.hypot(lx - r.x_m, ly - r.y_m)

    # --- the chain ------------------------------------------------------------------
    def _hop_gain_db(self, k: int) -> float:
        """Antenna gain of hop k: the back node's NanoStation pointing error if it is a relay
        (its link servo aims at its leader, node k); omni APs and the command center 0 dB."""
        back = k + 1
        if 1 <= back <= len(self.relays):
            r = self.relays[back - 1]
            fx, fy = self.node_pos(k)
            if self._dominant:
                want = self.radio.arrival_deg(r.pos, (fx, fy))
            else:
                want = math.degrees(math.atan2(fy - r.y_m, fx - r.x_m))
            off = wrap_deg(want - (r.theta_deg + r.link_deg))
            return patch_gain_db(off, self.radio.params.patch_floor_db)
        return 0.0

    def hop(self, k: int) -> Hop:
        a, b = self.node_pos(k), self.node_pos(k + 1)
        power, _ = self.radio.mean_power_dbm(a, b, self._hop_gain_db(k))
        _, n_walls = self.radio.wall_loss_db(a, b)
        # Multipath costs rate, not signal (relayd/sim/zones.py): the rate sees the penalty.
        phy = phy_rate_mbps(power - self.radio.rate_penalty_db(a, b), self.radio.params.rate_table)
        return Hop(k, power, phy * MAC_EFFICIENCY, n_walls, phy)

    def links(self) -> LinkBudget:
        return LinkBudget(
            [self.hop(k) for k in range(len(self.relays) + 1)], self.radio.params.hop_coupling
        )

    def hop_sample_dbm(self, k: int) -> float:
        """A reported (faded) signal level of hop k, as an airOS radio shows it."""
        a, b = self.node_pos(k), self.node_pos(k + 1)
        return self.radio.sample_dbm(a, b, self._hop_gain_db(k))

    def collisions(self) -> int:
        return sum(r.collisions for r in self.relays)
