"""Procedural town templates: each turns ``(seed, size)`` into a road graph for the builder.

Templates: ``grid`` (city blocks with signalized, all-way-stop and priority four-way junctions),
``metro`` (a grid with a highway joined by ramps), ``metro2`` (the held-out test town: ``metro``
reshaped with road structures no other template builds, see :mod:`.metro2`),
``tjunction`` (a main road with T-junctions), ``arterial`` (a wide road with parking lanes,
mid-block crosswalks and side streets), ``highway`` (a multi-lane road section with an off-ramp and
an on-ramp).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .builder import END, Node, Road, build_town
from .model import MERGE, PRIORITY, RAMP, SIGNAL, STOP, Town

TemplateFn = Callable[[np.random.Generator, int], tuple[list[Node], list[Road]]]


def _control(rng: np.random.Generator) -> int:
    return int(rng.choice([SIGNAL, STOP, PRIORITY], p=[0.45, 0.25, 0.30]))


def grid(rng: np.random.Generator, size: int = 3) -> tuple[list[Node], list[Road]]:
    """``size x size`` junction lattice with stub roads leaving the map on every side."""
    spacing = rng.uniform(85.0, 115.0, size=2)
    nodes: list[Node] = []
    ids = {}
    for i in range(size):
        for k in range(size):
            jitter = rng.uniform(-6.0, 6.0, size=2)
            ids[(i, k)] = len(nodes)
            nodes.append(Node(len(nodes), (i * spacing[0] + jitter[0], k * spacing[1] + jitter[1]), _control(rng)))
    roads: list[Road] = []
    lanes_x = rng.choice([1, 2], size=size, p=[0.5, 0.5])  # per row of east-west roads
    lanes_y = rng.choice([1, 2], size=size, p=[0.6, 0.4])
    parking_x = rng.random(size) < 0.4

    def add(a: int, b: int, n: int, parking: bool) -> None:
        mid = (0.5,) if rng.random() < 0.25 else ()
        roads.append(Road(len(roads), a, b, n, n, parking=parking, midblock_crosswalks=mid))

    for i in range(size):
        for k in range(size):
            if i + 1 < size:
                add(ids[(i, k)], ids[(i + 1, k)], int(lanes_x[k]), bool(parking_x[k]))
            if k + 1 < size:
                add(ids[(i, k)], ids[(i, k + 1)], int(lanes_y[i]), False)
    # stubs on the border so every border junction has four arms
    stub = 70.0
    for i in range(size):
        for k, d in ((0, (0.0, -1.0)), (size - 1, (0.0, 1.0))):
            p = nodes[ids[(i, k)]].pos
            e = Node(len(nodes), (p[0] + d[0] * stub, p[1] + d[1] * stub), END)
            nodes.append(e)
            a, b = (e.id, ids[(i, k)]) if d[1] < 0 else (ids[(i, k)], e.id)
            roads.append(Road(len(roads), a, b, int(lanes_y[i]), int(lanes_y[i])))
    for k in range(size):
        for i, d in ((0, (-1.0, 0.0)), (size - 1, (1.0, 0.0))):
            p = nodes[ids[(i, k)]].pos
            e = Node(len(nodes), (p[0] + d[0] * stub, p[1] + d[1] * stub), END)
            nodes.append(e)
            a, b = (e.id, ids[(i, k)]) if d[0] < 0 else (ids[(i, k)], e.id)
            roads.append(Road(len(roads), a, b, int(lanes_x[k]), int(lanes_x[k]), parking=bool(parking_x[k])))
    _priority_minors(nodes, roads)
    return nodes, roads


def _priority_minors(nodes: list[Node], roads: list[Road]) -> None:
    """At priority junctions, roads with fewer lanes (or the north-south ones) must stop."""
    for n in nodes:
        if n.control != PRIORITY:
            continue
        inc = [r for r in roads if n.id in (r.a, r.b)]
        most = max(r.lanes_fwd for r in inc)
        minors = {r.id for r in inc if r.lanes_fwd < most}
        if not minors:
            for r in inc:
                a, b = nodes[r.a].pos, nodes[r.b].pos
                if abs(b[1] - a[1]) > abs(b[0] - a[0]):
                    minors.add(r.id)
        n.minor_roads = minors


def tjunction(rng: np.random.Generator, size: int = 4) -> tuple[list[Node], list[Road]]:
    """A main east-west road with ``size`` T-junctions, side roads alternating north and south."""
    gaps = rng.uniform(80.0, 120.0, size=size + 1)
    xs = np.concatenate([[0.0], np.cumsum(gaps)])
    nodes = [Node(0, (0.0, 0.0), END)]
    roads: list[Road] = []
    main_lanes = int(rng.choice([1, 2]))
    prev = 0
    for i in range(1, size + 1):
        n = Node(len(nodes), (float(xs[i]), 0.0), int(rng.choice([SIGNAL, PRIORITY, STOP], p=[0.3, 0.5, 0.2])))
        nodes.append(n)
        roads.append(Road(len(roads), prev, n.id, main_lanes, main_lanes, parking=bool(rng.random() < 0.3)))
        side = 1.0 if i % 2 else -1.0
        e = Node(len(nodes), (float(xs[i] + rng.uniform(-5, 5)), side * float(rng.uniform(70, 100))), END)
        nodes.append(e)
        roads.append(Road(len(roads), n.id, e.id, 1, 1, parking=bool(rng.random() < 0.5)))
        n.minor_roads = {roads[-1].id}
        prev = n.id
    end = Node(len(nodes), (float(xs[-1]), 0.0), END)
    nodes.append(end)
    roads.append(Road(len(roads), prev, end.id, main_lanes, main_lanes))
    return nodes, roads


def arterial(rng: np.random.Generator, size: int = 3) -> tuple[list[Node], list[Road]]:
    """A two-lane-each-way arterial with parking lanes, mid-block crosswalks and side streets."""
    nodes = [Node(0, (0.0, 0.0), END)]
    roads: list[Road] = []
    prev = 0
    x = 0.0
    for _ in range(size):
        x += float(rng.uniform(120.0, 170.0))
        n = Node(len(nodes), (x, 0.0), int(rng.choice([SIGNAL, PRIORITY], p=[0.6, 0.4])))
        nodes.append(n)
        roads.append(Road(len(roads), prev, n.id, 2, 2, parking=True, midblock_crosswalks=(0.5,)))
        for side in (1.0, -1.0):
            e = Node(len(nodes), (x, side * float(rng.uniform(70.0, 90.0))), END)
            nodes.append(e)
            roads.append(Road(len(roads), n.id, e.id, 1, 1, speed_limit=8.3, parking=bool(rng.random() < 0.5)))
            n.minor_roads.add(roads[-1].id)
        prev = n.id
    end = Node(len(nodes), (x + float(rng.uniform(120.0, 170.0)), 0.0), END)
    nodes.append(end)
    roads.append(Road(len(roads), prev, end.id, 2, 2, parking=True, midblock_crosswalks=(0.5,)))
    return nodes, roads


def highway(rng: np.random.Generator, size: int = 3) -> tuple[list[Node], list[Road]]:
    """A ``size``-lane-each-way highway section with one off-ramp and one on-ramp (eastbound)."""
    lanes = max(2, size)
    v = 27.8  # m/s (100 km/h)
    x1, x2, x3 = 250.0, 250.0 + float(rng.uniform(250, 350)), 0.0
    x3 = x2 + 300.0
    nodes = [
        Node(0, (0.0, 0.0), END),
        Node(1, (x1, 0.0), MERGE),  # off-ramp diverge
        Node(2, (x2, 0.0), MERGE),  # on-ramp merge
        Node(3, (x3, 0.0), END),
        Node(4, (x1 + 120.0, -80.0), END),  # off-ramp end
        Node(5, (x2 - 120.0, -80.0), END),  # on-ramp start
    ]
    off = lanes * 3.5 + 1.0
    roads = [
        Road(0, 0, 1, lanes, lanes, speed_limit=v, sidewalks=False),
        Road(1, 1, 2, lanes, lanes, speed_limit=v, sidewalks=False),
        Road(2, 2, 3, lanes, lanes, speed_limit=v, sidewalks=False),
        Road(3, 1, 4, 1, 0, speed_limit=16.7, sidewalks=False, kind=RAMP,
             via=((x1 + 5.0, -(lanes * 3.5 + 1.75)), (x1 + 50.0, -off - 4.0), (x1 + 100.0, -40.0))),
        Road(4, 5, 2, 1, 0, speed_limit=16.7, sidewalks=False, kind=RAMP,
             via=((x2 - 100.0, -40.0), (x2 - 50.0, -off - 4.0), (x2 - 5.0, -(lanes * 3.5 + 1.75)))),
    ]
    return nodes, roads


def metro(rng: np.random.Generator, size: int = 4) -> tuple[list[Node], list[Road]]:
    """A ``size x size`` grid city with a highway south of it, joined by an off- and an on-ramp.

    The held-out test town uses it so that every scenario type (highway ones included) has a site
    in a town never used for training.
    """
    nodes, roads = grid(rng, size)
    # the southern stub ends of the grid (END nodes below the lowest junction row)
    south = sorted((n for n in nodes if n.control == END and n.pos[1] < -20.0), key=lambda n: n.pos[0])
    y = min(n.pos[1] for n in south) - 90.0
    x0 = min(n.pos[0] for n in nodes) - 150.0
    x3 = max(n.pos[0] for n in nodes) + 150.0
    # westbound traffic (north carriageway) leaves east of the grid and joins west of it
    exit_to, entry_from = south[-2], south[1]
    x1, x2 = exit_to.pos[0] + 170.0, entry_from.pos[0] - 170.0  # diverge, merge (x2 < x1)
    base = len(nodes)
    hw = [Node(base, (x0, y), END), Node(base + 1, (x2, y), MERGE), Node(base + 2, (x1, y), MERGE),
          Node(base + 3, (x3, y), END)]
    nodes += hw
    v, lanes = 27.8, 3
    off = lanes * 3.5 + 1.0
    for a, b in ((0, 1), (1, 2), (2, 3)):
        roads.append(Road(len(roads), hw[a].id, hw[b].id, lanes, lanes, speed_limit=v, sidewalks=False))
    # off-ramp: westbound carriageway at x1 -> the stub end, which becomes a bend into the grid
    ex, ey = exit_to.pos
    roads.append(Road(len(roads), hw[2].id, exit_to.id, 1, 0, speed_limit=16.7, sidewalks=False, kind=RAMP,
                      via=((x1 - 5.0, y + lanes * 3.5 + 1.75), (x1 - 60.0, y + off + 4.0), (ex + 40.0, y + 45.0),
                           (ex, ey - 25.0))))
    # on-ramp: from another stub end down into the westbound carriageway at x2
    nx, ny = entry_from.pos
    roads.append(Road(len(roads), entry_from.id, hw[1].id, 1, 0, speed_limit=16.7, sidewalks=False, kind=RAMP,
                      via=((nx, ny - 25.0), (nx - 40.0, y + 45.0), (x2 + 60.0, y + off + 4.0),
                           (x2 + 5.0, y + lanes * 3.5 + 1.75))))
    exit_to.control = entry_from.control = MERGE
    return nodes, roads


from .metro2 import metro2  # noqa: E402  (metro2 builds on grid, defined above)

TEMPLATES: dict[str, TemplateFn] = {
    "metro2": metro2,
    "metro": metro,
    "grid": grid,
    "tjunction": tjunction,
    "arterial": arterial,
    "highway": highway,
}


def generate_town(template: str, seed: int, size: int | None = None, name: str | None = None) -> Town:
    """Generate a town from a template name and a seed (deterministic).

    Raises:
        ValueError: unknown template.
    """
    if template not in TEMPLATES:
        raise ValueError(f"unknown town template {template!r}; known: {', '.join(sorted(TEMPLATES))}")
    rng = np.random.default_rng(seed)
    fn = TEMPLATES[template]
    nodes, roads = fn(rng) if size is None else fn(rng, size)
    return build_town(name or f"{template}-{seed}", template, seed, nodes, roads, rng)
