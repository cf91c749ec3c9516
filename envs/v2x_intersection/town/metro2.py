"""The held-out test town's template, ``metro2``: road structures no training template builds.

It starts from the training towns' ``grid`` city (the same draws as ``metro``) and reshapes it:

- every street (a grid row or column, its stubs included) gets its own lane width (3.0-3.8 m)
  and speed limit (30 / 40 / 50 / 60 km/h), where the training towns use 3.5 m everywhere;
- the northern row becomes a curved arterial: each block is a smooth arc (``via`` points), the
  arcs alternating so the road waves through its junctions at about 18 degrees off square;
- a diagonal avenue joins two interior junctions into two five-way junctions, their other arms
  bent so that neighbouring arms meet at about 60-90 degrees;
- one interior junction becomes a skewed crossing whose roads meet at 60 degrees;
- one junction on the eastern edge becomes a single-lane roundabout: a closed ring of one-way
  arcs running counter-clockwise between four priority nodes, where entering traffic stops and
  yields to the circulating traffic (the ring is the major road);
- a highway south of the city, joined to it by an off-ramp and an on-ramp (as ``metro``), with
  3.75 m lanes.
"""

from __future__ import annotations

import numpy as np

from . import templates as _templates
from .builder import END, Node, Road
from .model import MERGE, PRIORITY, RAMP, SIGNAL, STOP

KMH = 1.0 / 3.6
#: per-street (lane width m, speed limit m/s) choices: two-lane streets, one-lane streets
WIDE_STREETS = ((3.3, 50 * KMH), (3.6, 50 * KMH), (3.8, 60 * KMH), (3.6, 60 * KMH))
NARROW_STREETS = ((3.0, 30 * KMH), (3.2, 30 * KMH), (3.2, 40 * KMH), (3.4, 40 * KMH))
RING_RADIUS = 32.0  # m, roundabout centre line
RING_SPEED = 25 * KMH
RING_WIDTH = 4.0  # m, the ring's one lane
CURVE_TILT = np.radians(18.0)  # the curved arterial's heading at its junctions, off the row's line
SKEW = np.radians(60.0)  # angle between the skewed crossing's roads
HIGHWAY_WIDTH, HIGHWAY_SPEED = 3.75, 100 * KMH
#: m of westbound highway before the off-ramp's diverge: a route that leaves by the off-ramp
#: (HighwayExit) needs a run-up at highway speed to merge into the exit lane's flow
HIGHWAY_RUN_UP = 300.0


def _road_between(roads: list[Road], a: int, b: int) -> Road:
    """The road joining nodes ``a`` and ``b`` (either direction)."""
    for r in roads:
        if {r.a, r.b} == {a, b}:
            return r
    raise ValueError(f"metro2: no road between nodes {a} and {b}")


def _bezier_via(p0: np.ndarray, h0: float, p1: np.ndarray, h1: float, step: float = 5.0) -> tuple:
    """Interior points of a smooth cubic curve leaving ``p0`` with heading ``h0`` and arriving at
    ``p1`` with heading ``h1`` (rad), about ``step`` m apart (a road's ``via``)."""
    d = float(np.linalg.norm(p1 - p0))
    k = 0.38 * d
    c0 = p0 + k * np.array([np.cos(h0), np.sin(h0)])
    c1 = p1 - k * np.array([np.cos(h1), np.sin(h1)])
    t = np.linspace(0.0, 1.0, max(3, int(d / step)) + 1)[1:-1, None]
    pts = (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * c0 + 3 * (1 - t) * t**2 * c1 + t**3 * p1
    return tuple((float(x), float(y)) for x, y in pts)


def _shape_roads(nodes: list[Node], roads: list[Road], arm_dir: dict[tuple[int, int], float]) -> None:
    """Give every road with a prescribed arm direction at either end (``arm_dir[(road, node)]``:
    the heading from the node out along the road, rad) a smooth ``via`` curve meeting it."""
    for r in roads:
        if (r.id, r.a) not in arm_dir and (r.id, r.b) not in arm_dir:
            continue
        pa, pb = np.array(nodes[r.a].pos, float), np.array(nodes[r.b].pos, float)
        chord = float(np.arctan2(*(pb - pa)[::-1]))
        h0 = arm_dir.get((r.id, r.a), chord)
        h1 = arm_dir.get((r.id, r.b), chord + np.pi) - np.pi  # arriving heading
        r.via = _bezier_via(pa, h0, pb, h1)


def _roundabout(nodes: list[Node], roads: list[Road], centre: int) -> list[int]:
    """Replace junction node ``centre`` by a counter-clockwise ring of one-way roads between one
    priority node per arm (the arm's road is the minor one); returns the ring roads' ids."""
    c = np.array(nodes[centre].pos, float)
    arms = [r for r in roads if centre in (r.a, r.b)]
    ring = []
    for r in arms:
        far = nodes[r.b if r.a == centre else r.a]
        ang = float(np.arctan2(far.pos[1] - c[1], far.pos[0] - c[0]))
        n = Node(len(nodes), (float(c[0] + RING_RADIUS * np.cos(ang)),
                              float(c[1] + RING_RADIUS * np.sin(ang))), PRIORITY, {r.id})
        nodes.append(n)
        if r.a == centre:
            r.a = n.id
        else:
            r.b = n.id
        r.lanes_fwd = r.lanes_bwd = 1
        r.parking = False
        r.midblock_crosswalks = ()
        ring.append((ang % (2 * np.pi), n.id))
    nodes[centre].control = END  # no roads left: the builder skips it
    ring.sort()
    ids = []
    for k, (a0, n0) in enumerate(ring):
        a1, n1 = ring[(k + 1) % len(ring)]
        a1 = a1 if a1 > a0 else a1 + 2 * np.pi
        steps = np.linspace(a0, a1, max(3, int(np.degrees(a1 - a0) / 6.0)) + 1)[1:-1]
        via = tuple((float(c[0] + RING_RADIUS * np.cos(t)), float(c[1] + RING_RADIUS * np.sin(t)))
                    for t in steps)
        ids.append(len(roads))
        roads.append(Road(len(roads), n0, n1, 1, 0, lane_width=RING_WIDTH, speed_limit=RING_SPEED,
                          sidewalks=False, via=via))
    return ids


def _street_profiles(rng: np.random.Generator, nodes: list[Node], roads: list[Road], size: int) -> None:
    """One lane width and speed limit per street: grid rows, grid columns and the other roads,
    drawn by how many lanes the street has."""
    def street(r: Road) -> tuple[str, int]:
        a, b = np.array(nodes[r.a].pos), np.array(nodes[r.b].pos)
        ends = [n for n in (r.a, r.b) if n < size * size]
        if len(ends) == 2 and r.a // size != r.b // size and r.a % size == r.b % size:
            return "row", r.a % size
        if len(ends) == 2 and r.a // size == r.b // size:
            return "col", r.a // size
        if len(ends) == 1 and not r.via:  # a stub: its grid node's row or column
            horizontal = abs(b[0] - a[0]) > abs(b[1] - a[1])
            return ("row", ends[0] % size) if horizontal else ("col", ends[0] // size)
        return "road", r.id

    profile: dict[tuple[str, int], tuple[float, float]] = {}
    for r in roads:
        if r.lanes_bwd == 0:  # the roundabout's ring keeps its own profile
            continue
        key = street(r)
        if key not in profile:
            table = WIDE_STREETS if r.lanes_fwd >= 2 else NARROW_STREETS
            profile[key] = table[int(rng.integers(len(table)))]
        r.lane_width, r.speed_limit = profile[key]


def _highway(nodes: list[Node], roads: list[Road]) -> None:
    """A 3-lane-each-way highway south of the city joined to two southern stubs by an off-ramp and
    an on-ramp (``metro``'s layout, with :data:`HIGHWAY_WIDTH` lanes)."""
    south = sorted((n for n in nodes if n.control == END and n.pos[1] < -20.0
                    and any(n.id in (r.a, r.b) for r in roads)), key=lambda n: n.pos[0])
    y = min(n.pos[1] for n in south) - 90.0
    x0 = min(n.pos[0] for n in nodes) - 150.0
    exit_to, entry_from = south[-2], south[1]
    x1, x2 = exit_to.pos[0] + 170.0, entry_from.pos[0] - 170.0
    x3 = max(max(n.pos[0] for n in nodes) + 150.0, x1 + HIGHWAY_RUN_UP)
    base = len(nodes)
    hw = [Node(base, (x0, y), END), Node(base + 1, (x2, y), MERGE),
          Node(base + 2, (x1, y), MERGE), Node(base + 3, (x3, y), END)]
    nodes += hw
    lanes, w = 3, HIGHWAY_WIDTH
    off = lanes * w + 1.0
    for a, b in ((0, 1), (1, 2), (2, 3)):
        roads.append(Road(len(roads), hw[a].id, hw[b].id, lanes, lanes, lane_width=w,
                          speed_limit=HIGHWAY_SPEED, sidewalks=False))
    ramp = dict(speed_limit=60 * KMH, sidewalks=False, kind=RAMP, lane_width=3.6)
    ex, ey = exit_to.pos
    roads.append(Road(len(roads), hw[2].id, exit_to.id, 1, 0, via=(
        (x1 - 5.0, y + lanes * w + 1.8), (x1 - 60.0, y + off + 4.0), (ex + 40.0, y + 45.0),
        (ex, ey - 25.0)), **ramp))
    nx, ny = entry_from.pos
    roads.append(Road(len(roads), entry_from.id, hw[1].id, 1, 0, via=(
        (nx, ny - 25.0), (nx - 40.0, y + 45.0), (x2 + 60.0, y + off + 4.0),
        (x2 + 5.0, y + lanes * w + 1.8)), **ramp))
    exit_to.control = entry_from.control = MERGE


def metro2(rng: np.random.Generator, size: int = 4) -> tuple[list[Node], list[Road]]:
    """The ``size x size`` (``size >= 4``) grid city reshaped as the module docstring says, with
    a highway south of it."""
    if size < 4:
        raise ValueError(f"metro2: size must be >= 4 (got {size}): it needs 2 x 2 interior junctions")
    nodes, roads = _templates.grid(rng, size)

    def gid(i: int, k: int) -> int:
        return i * size + k

    def rd(a: tuple[int, int], b: tuple[int, int]) -> Road:
        return _road_between(roads, gid(*a), gid(*b))

    arm_dir: dict[tuple[int, int], float] = {}
    deg = np.radians
    # five-way junctions at (1, 1) and (2, 2), joined by a one-lane diagonal avenue
    five_a, five_b = gid(1, 1), gid(2, 2)
    diag = Road(len(roads), five_a, five_b, 1, 1)
    roads.append(diag)
    arm_dir[(diag.id, five_a)] = deg(45.0)
    arm_dir[(diag.id, five_b)] = deg(225.0)
    arm_dir[(rd((1, 1), (2, 1)).id, five_a)] = deg(-20.0)
    arm_dir[(rd((1, 1), (1, 2)).id, five_a)] = deg(110.0)
    arm_dir[(rd((1, 2), (2, 2)).id, five_b)] = deg(160.0)
    arm_dir[(rd((2, 1), (2, 2)).id, five_b)] = deg(290.0)
    nodes[five_a].control, nodes[five_b].control = STOP, SIGNAL
    # skewed crossing at (2, 1): its north-south road turns to meet the east-west one at SKEW
    skew = gid(2, 1)
    arm_dir[(rd((2, 1), (2, 2)).id, skew)] = SKEW
    arm_dir[(rd((2, 0), (2, 1)).id, skew)] = SKEW + np.pi
    arm_dir[(rd((1, 1), (2, 1)).id, skew)] = np.pi
    arm_dir[(rd((2, 1), (3, 1)).id, skew)] = 0.0
    nodes[skew].control = PRIORITY
    # the northern row waves through its junctions (a curved arterial)
    top = size - 1
    for i in range(size):
        tilt = CURVE_TILT if i % 2 == 0 else -CURVE_TILT
        row = [r for r in roads if gid(i, top) in (r.a, r.b)
               and abs(nodes[r.b].pos[1] - nodes[r.a].pos[1]) < abs(nodes[r.b].pos[0] - nodes[r.a].pos[0])]
        for r in row:
            other = nodes[r.b if r.a == gid(i, top) else r.a]
            east = other.pos[0] > nodes[gid(i, top)].pos[0]
            arm_dir[(r.id, gid(i, top))] = tilt if east else tilt + np.pi
    # a roundabout in place of the eastern edge's second junction from the south
    _roundabout(nodes, roads, gid(size - 1, 1))
    _shape_roads(nodes, roads, arm_dir)
    _street_profiles(rng, nodes, roads, size)
    _templates._priority_minors(nodes, roads)
    for n in nodes:  # ring nodes: the arm's road is minor (priority_minors picked by lane counts)
        if n.control == PRIORITY and any(r.lanes_bwd == 0 and n.id in (r.a, r.b) for r in roads):
            n.minor_roads = {r.id for r in roads if n.id in (r.a, r.b) and r.lanes_bwd > 0}
    skew_roads = {r.id for r in roads if skew in (r.a, r.b)}
    nodes[skew].minor_roads = {r.id for r in roads if r.id in skew_roads
                               and abs(nodes[r.b].pos[0] - nodes[r.a].pos[0]) < 60.0}
    _highway(nodes, roads)
    return nodes, roads
