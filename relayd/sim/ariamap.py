"""ARIA 2-D map files (`.map`, made by ARIA's mapping tools): a pure parser.

A map is a header (`Key: value` lines, among them `Cairn:` objects), then a `LINES`
section (one wall per line: `x1 y1 x2 y2`, millimetres) and a `DATA` section (one scan
point per line: `x y`). What relayd reads of it:

- `LINES`: wall segments;
- `DATA`: obstacle points (what a laser saw; furniture often exists only as points);
- `Cairn: RobotHome x y th ...`: start poses;
- `Cairn: Goal x y th ... "name"`: the leader's waypoints;
- `Cairn: Sim.BoxObstacle 0 0 0 "" ICON "" x1 y1 x2 y2`: boxes (MobileSim's obstacles);
- `Resolution:` the points' size (default 20 mm, as MobileSim's).

Everything else (docks, forbidden lines, map info) is kept as objects and otherwise
ignored. Coordinates come back in metres. A line that cannot be read raises MapError
naming the file and the line number. relayd/sim/mapscenario.py makes a scenario of it.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass, field
from pathlib import Path

#: MobileSim's and ARIA's default map resolution (the size of a scan point).
DEFAULT_RESOLUTION_MM = 20


class MapError(ValueError):
    """A map that cannot be read; the message names the file and the line."""


@dataclass(frozen=True, slots=True)
class MapLine:
    """One `LINES` entry, in metres, with its line number in the file."""

    x1: float
    y1: float
    x2: float
    y2: float
    lineno: int


@dataclass(frozen=True, slots=True)
class MapObject:
    """One `Cairn:` object: its type, pose (m, deg), name and optional rectangle (m)."""

    kind: str
    x: float
    y: float
    theta_deg: float
    name: str
    lineno: int
    rect: tuple[float, float, float, float] | None = None


@dataclass(frozen=True, slots=True)
class AriaMap:
    source: str
    lines: tuple[MapLine, ...]
    points: tuple[tuple[float, float], ...]
    objects: tuple[MapObject, ...]
    resolution_m: float = DEFAULT_RESOLUTION_MM / 1000.0
    header: dict[str, str] = field(default_factory=dict)

    def of_kind(self, kind: str) -> list[MapObject]:
        return [o for o in self.objects if o.kind == kind]

    @property
    def homes(self) -> list[MapObject]:
        return self.of_kind("RobotHome")

    @property
    def goals(self) -> list[MapObject]:
        return self.of_kind("Goal")

    @property
    def boxes(self) -> list[MapObject]:
        return [o for o in self.of_kind("Sim.BoxObstacle") if o.rect is not None]

    def bounds(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the lines and points, metres."""
        xs = [v for ln in self.lines for v in (ln.x1, ln.x2)] + [p[0] for p in self.points]
        ys = [v for ln in self.lines for v in (ln.y1, ln.y2)] + [p[1] for p in self.points]
        if not xs:
            return 0.0, 0.0, 0.0, 0.0
        return min(xs), min(ys), max(xs), max(ys)


def _numbers(parts: list[str], n: int, where: str, what: str) -> list[float]:
    if len(parts) != n:
        raise MapError(f"{where}: {what} needs {n} numbers, got {len(parts)}")
    try:
        return [float(p) for p in parts]
    except ValueError:
        raise MapError(f"{where}: {what} needs numbers, got {' '.join(parts)!r}") from None


def _cairn(rest: str, where: str, lineno: int) -> MapObject:
    """`TYPE x y th "desc" ICON "name" [x1 y1 x2 y2]` (ArMapObject's text form)."""
    try:
        parts = shlex.split(rest)
    except ValueError as exc:
        raise MapError(f"{where}: Cairn: {exc}") from None
    if len(parts) < 4:
        raise MapError(f"{where}: Cairn needs a type, x, y and theta")
    x, y, th = _numbers(parts[1:4], 3, where, f"Cairn {parts[0]} pose")
    name = parts[6] if len(parts) > 6 else ""
    rect = None
    if len(parts) >= 11:
        x1, y1, x2, y2 = _numbers(parts[7:11], 4, where, f"Cairn {parts[0]} rectangle")
        rect = (x1 / 1000.0, y1 / 1000.0, x2 / 1000.0, y2 / 1000.0)
    return MapObject(parts[0], x / 1000.0, y / 1000.0, th, name, lineno, rect)


def parse_map(text: str, source: str = "<map>") -> AriaMap:
    """Read an ARIA map's text. Raises MapError naming `source` and the line."""
    lines: list[MapLine] = []
    points: list[tuple[float, float]] = []
    objects: list[MapObject] = []
    header: dict[str, str] = {}
    section = "header"
    seen_magic = False
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        where = f"{source}:{lineno}"
        if not seen_magic:
            if not line.startswith("2D-Map"):
                raise MapError(f"{where}: not an ARIA map (the first line must be 2D-Map)")
            seen_magic = True
            continue
        if line in ("LINES", "DATA"):
            section = line
            continue
        if line.endswith("_END") or line.startswith("ScanId:"):
            continue  # 2D-Map-Ex section ends and scan ids: nothing to read
        if section == "LINES":
            x1, y1, x2, y2 = _numbers(line.split(), 4, where, "LINES entry")
            lines.append(MapLine(x1 / 1000.0, y1 / 1000.0, x2 / 1000.0, y2 / 1000.0, lineno))
        elif section == "DATA":
            px, py = _numbers(line.split(), 2, where, "DATA point")
            points.append((px / 1000.0, py / 1000.0))
        else:
            key, sep, rest = line.partition(":")
            if not sep or not key or " " in key:
                raise MapError(f"{where}: expected 'Key: value', LINES or DATA, got {line[:40]!r}")
            if key == "Cairn":
                objects.append(_cairn(rest, where, lineno))
            else:
                header.setdefault(key, rest.strip())
    if not seen_magic:
        raise MapError(f"{source}:1: empty file, not an ARIA map")
    resolution_m = DEFAULT_RESOLUTION_MM / 1000.0
    if "Resolution" in header:
        try:
            resolution_m = float(header["Resolution"]) / 1000.0
        except ValueError:
            raise MapError(
                f"{source}: Resolution: not a number: {header['Resolution']!r}"
            ) from None
        if resolution_m <= 0:
            raise MapError(f"{source}: Resolution: must be > 0")
    return AriaMap(source, tuple(lines), tuple(points), tuple(objects), resolution_m, header)


def load_map(path: str | Path) -> AriaMap:
    """Read an ARIA map file (MapError on an unreadable file or a bad line)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise MapError(f"{p}: {exc.strerror or exc}") from None
    # Map files are ASCII; names in Cairn objects may be Latin-1 (ARIA writes bytes).
    return parse_map(raw.decode("latin-1"), str(p))
