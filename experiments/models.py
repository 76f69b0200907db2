"""Generators of standard Dec-POMDP benchmark models in MADP's ``.dpomdp`` format, written
from the published rules (the MADP files themselves are their authors' and not part of this
repository).

    python experiments/models.py fire-fighting --houses 4 --levels 3 --out ff243.dpomdp
    python experiments/models.py fire-fighting --houses 3 --levels 3 --out ff233.dpomdp
    python experiments/models.py mars --out mars.dpomdp
    python experiments/models.py meeting-grid --out grid3x3corners.dpomdp

**Fire fighting** (Oliehoek, Spaan and Vlassis 2008, "Optimal and approximate Q-value functions
for decentralized POMDPs", JAIR 32; MADP's ``ProblemFireFighting`` in the form its distributed
``fireFighting_<agents>_<houses>_<levels>.dpomdp`` files take):

* houses ``1..H`` in a row, each with a fire level ``0..F-1``; each agent chooses a house to go
  to (``go1 .. goH``) and observes ``flames`` / ``noFlames`` at that house;
* the state holds every house's fire level and every agent's position (the house it went to
  last, or ``start`` before its first move): ``F**H * (H + 1)**agents`` states -- 432 for
  2 agents, 3 houses, 3 levels; 2025 for 2 agents, 4 houses, 3 levels -- named
  ``f<l1>_.._f<lH>_<pos1>_<pos2>`` and ordered with the last feature fastest;
* the episode starts with every agent at ``start`` and the fire levels uniform;
* each house moves independently (``n`` agents at it, "a neighbour burns" = house ``h-1`` or
  ``h+1`` has a level > 0 before the step; levels clipped to ``0..F-1``):

  =====  ====================  ==========================================
  ``n``  neighbour burns       next level
  =====  ====================  ==========================================
  0      yes                   same 0.2, one higher 0.8
  0      no, level 0           0
  0      no, level > 0         same 0.6, one higher 0.4
  1      yes                   same 0.4, one lower 0.6
  1      no                    one lower (0 stays 0)
  >= 2   any                   0
  =====  ====================  ==========================================

* an agent sees ``flames`` with probability 0.2 / 0.5 / 0.8 when the level of its house after
  the step is 0 / 1 / >= 2 (the agents' observations independent);
* the reward is minus the sum of the fire levels after the step (``R: * : * : s' : * : r``,
  which MADP -- and ``cognet_jax.io.dpomdp`` -- turn into ``R(s, ja) = sum_s' T r``); the
  discount is 1.

Probabilities are written exactly (products of the table's decimals), so every row sums to 1.
MADP's files print them with two decimals (0.072 as 0.07), and the published optima are those
of the rounded model (fire fighting 2-3-3, horizon 2: -4.383496 rounded, -4.383579 exact);
``--madp-rounding`` (``fire_fighting(..., madp_rounding=True)``) writes them that way, where the
rounded rows still sum to 1 (3 houses; with 4 houses they would sum to 0.98-1.02, which MADP's
own check and this package's parser refuse).

**Box pushing** (Seuken and Zilberstein 2007, "Improved memory-bounded dynamic programming for
decentralized POMDPs", UAI; the 100-state ``boxPushingUAI07.dpomdp`` that MADP distributes,
extracted from the UMass code):

* two agents in the bottom row of a 3 x 4 grid, columns ``0..3``, agent 1 left of agent 2;
  above column 0 and column 3 a small box, above columns 1-2 the large box; each agent faces
  N, E, S or W;
* states ``4..99``: ``4 + off(p1) + o1 * 4 * (3 - p1) + 4 * (p2 - p1 - 1) + o2`` (columns
  ``p1 < p2``, orientations ``o`` 0 N, 1 E, 2 S, 3 W, ``off`` = 0, 48, 80 for ``p1`` = 0, 1,
  2); states 0 / 1 / 2 / 3: the left small box / the right small box / both small boxes / the
  large box was just pushed, from which every action leads to the start state 27 (column 0
  facing E, column 3 facing W) -- the episode begins again;
* actions 0 turn left, 1 turn right, 2 move forward, 3 stay; a turn or a move succeeds with
  probability 0.9 for each agent independently (else nothing happens);
* moving forward facing N pushes the box above: a small box alone (a success ends in state 0
  or 1, both small boxes in state 2, whatever the other agent does), the large box only when
  both agents push it together and both succeed (state 3; otherwise nobody moves); facing S,
  into the outer walls, into the other agent's cell (even when it moves away) or into the cell
  the other agent also enters (when both succeed; neither moves) the move is blocked;
* rewards ``R(s, ja)`` for what the agents attempt: -0.1 per agent and step, -5 per blocked
  forward move (a lone push on the large box included), +10 per push on a small box, +100 for
  the joint push on the large box; 0 in states 0-3;
* each agent sees the cell in front of it after the step (0 empty, 1 wall, 2 the other agent,
  3 small box, 4 large box; ``0 0`` in states 0-3); the discount is 1.

MADP's file has one transition that these rules do not give: from state 67 (column 1 facing
E, column 3 facing W) under ``2 2``, the outcome "agent 1 moves, agent 2 does not" (0.09) goes
to state 90 (agent 2 facing S) where the rules give 91. ``box_pushing(madp_quirk=True)`` (the
default) writes MADP's line, so the published optima (17.6, 66.081, 98.593, 107.72 at horizons
2 to 5) are those of the generated file; ``--rules-only`` writes 91.

**Mars rovers** (Amato and Zilberstein 2009, "Achieving goal-oriented behavior in decentralized
POMDPs", AAMAS; MADP's ``Mars.dpomdp``: 256 states, 6 actions and 8 observations per agent):
two rovers on a 2 x 2 grid whose four cells are sites: cells 0 and 3 are drill sites, 1 and 2
sample sites. The rules below are MADP's file's, quirks included (checked against a copy of it,
which is not part of this repository: transitions, observations, rewards and start equal).

* a state holds both rovers' cells and which sites are done: ``64 p1 + 16 p2 + done`` (a
  cell's bit 0 is its row, bit 1 its column; site ``c`` is bit ``c`` of ``done``); the episode
  starts with both rovers on cell 0 and no site done; the discount is 1;
* actions ``up, down, left, right, drill, sample``: a move succeeds with probability 0.9, else
  the rover stays (into the grid's edge it stays); ``drill`` and ``sample`` keep the rover in
  place and mark its cell's site done; an experiment after which every site is done sends the
  rovers to state 0;
* each rover observes its cell and whether that cell's site is done (after the step);
* rewards ``R(s, ja)``, with a rover's own value -0.1 for a move, and for an experiment -1 on a
  done site, else -10 drilling and +2 sampling: when either rover moves, the sum of both
  rovers' own values; both experimenting on one cell: -2 if its site is done, else on a drill
  site +6 both drilling, +1 both sampling, 0 mixed, and on a sample site +2 both sampling, 0
  otherwise; experimenting on two cells: rover 1's action counts for both sites (the sum of
  its own value at each), except that drilling two open sites gives 0.

**Meeting in a 3 x 3 grid with corners** (Amato, Dibangoye and Zilberstein 2009, "Incremental
policy generation for finite-horizon DEC-POMDPs", ICAPS; MADP's ``Grid3x3corners.dpomdp``:
81 states, 5 actions and 9 observations per agent), checked against MADP's file in the same way:

* a state is both agents' cells, ``9 c1 + c2`` (cell ``3 row + column``, row 0 on top); the
  episode starts with the agents in the top-right and the bottom-left corner (cells 2 and 6);
  the discount is 1;
* actions ``up, down, left, right, stay``: a move goes the intended way with probability 0.6,
  each of the other three ways with 0.1 and nowhere with 0.1 (a way into the grid's edge
  leaves the agent where it is); ``stay`` stays;
* each agent observes its own cell;
* reward 1 in every step the agents share the top-left or the bottom-right corner (the state
  before the step), 0 otherwise.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

#: P(flames) by the fire level of the agent's house after the step (levels >= 2 share the last)
FLAMES = (0.2, 0.5, 0.8)


def _number(p: float) -> str:
    """A probability or reward as a short exact decimal (``0.0384``, ``-3``)."""
    text = f"{p:.10f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


def house_next(level: int, agents_here: int, neighbour_burns: bool, levels: int) -> dict:
    """``{next level: probability}`` of one house (the table of the module docstring)."""
    top, up, down = levels - 1, min(level + 1, levels - 1), max(level - 1, 0)
    if agents_here >= 2:
        outcomes = [(0, 1.0)]
    elif agents_here == 1:
        outcomes = [(level, 0.4), (down, 0.6)] if neighbour_burns else [(down, 1.0)]
    elif neighbour_burns:
        outcomes = [(level, 0.2), (up, 0.8)]
    elif level == 0:
        outcomes = [(0, 1.0)]
    else:
        outcomes = [(level, 0.6), (up, 0.4)]
    dist: dict = {}
    for nxt, p in outcomes:
        dist[min(nxt, top)] = dist.get(min(nxt, top), 0.0) + p
    return dist


def fire_fighting(
    houses: int = 3, levels: int = 3, agents: int = 2, madp_rounding: bool = False
) -> str:
    """The ``.dpomdp`` text of fire fighting with ``agents`` agents, ``houses`` houses and
    ``levels`` fire levels (module docstring); ``madp_rounding``: transition probabilities
    with two decimals, as MADP prints them (a ``ValueError`` where a rounded row would not sum
    to 1)."""
    if houses < 1 or levels < 2 or agents < 1:
        raise ValueError("fire fighting needs houses >= 1, levels >= 2 and agents >= 1")
    positions = [f"h{h + 1}" for h in range(houses)] + ["start"]
    fires = list(itertools.product(range(levels), repeat=houses))
    places = list(itertools.product(range(houses + 1), repeat=agents))

    def name(fire, place) -> str:
        return "_".join([f"f{x}" for x in fire] + [positions[p] for p in place])

    starts = [name(fire, (houses,) * agents) for fire in fires]
    actions = " ".join(f"go{h + 1}" for h in range(houses))
    out = [
        f"# fire fighting: {agents} agents, {houses} houses, {levels} fire levels "
        "(experiments/models.py, from Oliehoek, Spaan and Vlassis 2008)",
        f"agents: {agents}",
        "discount: 1",
        "values: reward",
        "states: " + " ".join(name(f, p) for f in fires for p in places),
        "start include: " + " ".join(starts),
        "actions:",
        *[actions] * agents,
        "observations:",
        *["flames noFlames"] * agents,
    ]
    for joint in itertools.product(range(houses), repeat=agents):
        ja = " ".join(f"go{h + 1}" for h in joint)
        here = [joint.count(h) for h in range(houses)]
        for fire in fires:
            burns = [
                (h > 0 and fire[h - 1] > 0) or (h + 1 < houses and fire[h + 1] > 0)
                for h in range(houses)
            ]
            per_house = [house_next(fire[h], here[h], burns[h], levels) for h in range(houses)]
            nexts = [
                (nxt, round(p, 2) if madp_rounding else p)
                for nxt in itertools.product(*[sorted(d) for d in per_house])
                if (p := _product(d[x] for d, x in zip(per_house, nxt))) > 0
            ]
            total = sum(p for _, p in nexts)
            if abs(total - 1) > 1e-9:
                raise ValueError(
                    f"with two decimals the probabilities after fire levels {fire} and actions "
                    f"{ja} sum to {total:.4f}, not 1: write exact probabilities"
                )
            nexts = [(nxt, p) for nxt, p in nexts if p > 0]
            for place in places:
                s = name(fire, place)
                out += [f"T: {ja} : {s} : {name(nxt, joint)} : {_number(p)}" for nxt, p in nexts]
    observations = list(itertools.product(("flames", "noFlames"), repeat=agents))
    for fire in fires:
        for place in places:
            s = name(fire, place)
            seen = [FLAMES[min(fire[p], 2)] if p < houses else FLAMES[0] for p in place]
            for jo in observations:
                p = _product(q if o == "flames" else 1 - q for o, q in zip(jo, seen))
                out.append(f"O: * : {s} : {' '.join(jo)} : {_number(p)}")
            if sum(fire):
                out.append(f"R: * : * : {s} : * : {-sum(fire)}")
    return "\n".join(out) + "\n"


#: box pushing: orientation steps (N, E, S, W) and what an agent sees
NORTH, EAST, SOUTH, WEST = range(4)
EMPTY, WALL, AGENT, SMALL_BOX, LARGE_BOX = range(5)
START_STATE = 27


def box_state(p1: int, o1: int, p2: int, o2: int) -> int:
    """The index of a box-pushing configuration (module docstring)."""
    offset = {0: 0, 1: 48, 2: 80}[p1]
    return 4 + offset + o1 * 4 * (3 - p1) + 4 * (p2 - p1 - 1) + o2


def box_configurations() -> list[tuple[int, int, int, int]]:
    """``(p1, o1, p2, o2)`` of states ``4..99``, in index order."""
    configs = [
        (p1, o1, p2, o2)
        for p1 in range(3)
        for o1 in range(4)
        for p2 in range(p1 + 1, 4)
        for o2 in range(4)
    ]
    assert [box_state(*c) for c in configs] == list(range(4, 100))
    return configs


def _box_sees(me: int, facing: int, other: int) -> int:
    if facing == NORTH:
        return SMALL_BOX if me in (0, 3) else LARGE_BOX
    if facing == SOUTH:
        return WALL
    ahead = me + (1 if facing == EAST else -1)
    if not 0 <= ahead <= 3:
        return WALL
    return AGENT if ahead == other else EMPTY


def _box_step(config, actions, succeeded) -> int:
    """The next state of ``config`` when each agent's action ``succeeded`` (or not)."""
    p, o = [config[0], config[2]], [config[1], config[3]]
    moving = [a == 2 and ok for a, ok in zip(actions, succeeded)]
    small = [moving[i] and o[i] == NORTH and p[i] in (0, 3) for i in range(2)]
    if all(small):
        return 2
    if any(small):
        return 0 if p[small.index(True)] == 0 else 1
    if all(moving[i] and o[i] == NORTH and p[i] in (1, 2) for i in range(2)):
        return 3
    targets = [
        p[i] + (1 if o[i] == EAST else -1) if moving[i] and o[i] in (EAST, WEST) else None
        for i in range(2)
    ]
    new_p = list(p)
    for i in range(2):
        t = targets[i]
        if t is not None and 0 <= t <= 3 and t != p[1 - i] and t != targets[1 - i]:
            new_p[i] = t
    new_o = [
        (o[i] + (3 if actions[i] == 0 else 1)) % 4
        if actions[i] in (0, 1) and succeeded[i]
        else o[i]
        for i in range(2)
    ]
    return box_state(new_p[0], new_o[0], new_p[1], new_o[1])


def _box_reward(config, actions) -> float:
    p, o = [config[0], config[2]], [config[1], config[3]]
    forward = [a == 2 for a in actions]
    if all(forward[i] and o[i] == NORTH and p[i] in (1, 2) for i in range(2)):
        return 100 - 0.2
    targets = [p[i] + (1 if o[i] == EAST else -1) if o[i] in (EAST, WEST) else None for i in (0, 1)]
    reward = -0.2
    for i in range(2):
        if not forward[i]:
            continue
        if o[i] == NORTH:
            reward += 10 if p[i] in (0, 3) else -5
        elif o[i] == SOUTH:
            reward -= 5
        else:
            t = targets[i]
            same_cell = forward[1 - i] and targets[1 - i] == t
            if not 0 <= t <= 3 or t == p[1 - i] or same_cell:
                reward -= 5
    return round(reward, 10)


def box_pushing(madp_quirk: bool = True) -> str:
    """The ``.dpomdp`` text of box pushing (module docstring), in the layout of MADP's file:
    numbered states, actions and observations; T by state, joint action, next state."""
    out = [
        "# cooperative box pushing (experiments/models.py, from Seuken and Zilberstein 2007, in"
        " the layout of MADP's boxPushingUAI07.dpomdp)",
        "agents: 2",
        "discount: 1.0",
        "values: reward",
        "states: 100",
        f"start: {START_STATE}",
        "actions:",
        "4",
        "4",
        "observations:",
        "5",
        "5",
    ]
    configs = box_configurations()
    for s in range(4):
        out += [f"T: {a1} {a2} : {s} : {START_STATE} : 1.0" for a1 in range(4) for a2 in range(4)]
    for config in configs:
        s = box_state(*config)
        for actions in itertools.product(range(4), repeat=2):
            dist: dict = {}
            for succeeded in itertools.product((True, False), repeat=2):
                p = _product(
                    1.0 if a == 3 else (0.9 if ok else 0.1) for a, ok in zip(actions, succeeded)
                )
                if p == 0 or any(a == 3 and not ok for a, ok in zip(actions, succeeded)):
                    continue
                nxt = _box_step(config, actions, succeeded)
                if madp_quirk and s == 67 and actions == (2, 2) and succeeded == (True, False):
                    nxt = 90
                dist[nxt] = round(dist.get(nxt, 0.0) + p, 10)
            a1, a2 = actions
            out += [f"T: {a1} {a2} : {s} : {nxt} : {_number(dist[nxt])}" for nxt in sorted(dist)]
    for s in range(100):
        if s < 4:
            seen = (EMPTY, EMPTY)
        else:
            p1, o1, p2, o2 = configs[s - 4]
            seen = (_box_sees(p1, o1, p2), _box_sees(p2, o2, p1))
        out.append(f"O: * : {s} : {seen[0]} {seen[1]} : 1.0")
    for config in configs:
        s = box_state(*config)
        for a1, a2 in itertools.product(range(4), repeat=2):
            out.append(f"R: {a1} {a2} : {s} : * : * : {_number(_box_reward(config, (a1, a2)))}")
    return "\n".join(out) + "\n"


def _product(values) -> float:
    result = 1.0
    for v in values:
        result *= v
    return round(result, 10)


# ---------------------------------------------------------------------------------------------
# Mars rovers and meeting in a 3 x 3 grid (module docstring)
# ---------------------------------------------------------------------------------------------
#: Mars rovers: action -> (row step, column step); 4 drill and 5 sample stay
MARS_MOVES = {0: (-1, 0), 1: (1, 0), 2: (0, -1), 3: (0, 1)}
MARS_DRILL, MARS_SAMPLE = 4, 5
MARS_DRILL_SITES = (0, 3)
MARS_ALL_DONE = 0b1111


def mars_cell_moved(cell: int, action: int) -> int:
    """The cell a rover in ``cell`` of the 2 x 2 grid reaches when ``action`` succeeds (bit 0
    of a cell is its row, bit 1 its column); the same cell at the edge or for an experiment."""
    if action not in MARS_MOVES:
        return cell
    row, col = cell & 1, cell >> 1
    row, col = row + MARS_MOVES[action][0], col + MARS_MOVES[action][1]
    return cell if not (0 <= row < 2 and 0 <= col < 2) else row + 2 * col


def _mars_alone(action: int, open_site: bool) -> float:
    """One rover's reward for ``action`` at a site open (not yet done) or not."""
    if action in MARS_MOVES:
        return -0.1
    if not open_site:
        return -1.0
    return -10.0 if action == MARS_DRILL else 2.0


def mars_reward(cells: tuple[int, int], done: int, actions: tuple[int, int]) -> float:
    """``R(s, ja)`` of Mars rovers (module docstring): ``cells`` of both rovers, ``done`` the
    bits of the sites done."""
    open1, open2 = (not done >> c & 1 for c in cells)
    a1, a2 = actions
    if a1 in MARS_MOVES or a2 in MARS_MOVES:
        return round(_mars_alone(a1, open1) + _mars_alone(a2, open2), 10)
    if cells[0] == cells[1]:
        if not open1:
            return -2.0
        if cells[0] in MARS_DRILL_SITES:
            both = {(MARS_DRILL, MARS_DRILL): 6.0, (MARS_SAMPLE, MARS_SAMPLE): 1.0}
            return both.get(actions, 0.0)
        return 2.0 if actions == (MARS_SAMPLE, MARS_SAMPLE) else 0.0
    if a1 == MARS_DRILL and open1 and open2:
        return 0.0
    return round(_mars_alone(a1, open1) + _mars_alone(a1, open2), 10)


def _rover_outcomes(cell: int, action: int) -> dict:
    """``{next cell: probability}`` of one rover: a move into the grid succeeds with 0.9."""
    target = mars_cell_moved(cell, action)
    return {cell: 1.0} if target == cell else {target: 0.9, cell: 0.1}


def mars_next(cells: tuple[int, int], done: int, actions: tuple[int, int]) -> dict:
    """``{next state: probability}`` of Mars rovers (module docstring)."""
    after = done
    for cell, action in zip(cells, actions):
        if action not in MARS_MOVES:
            after |= 1 << cell
    if after == MARS_ALL_DONE and any(a not in MARS_MOVES for a in actions):
        return {0: 1.0}
    dist: dict = {}
    firsts, seconds = (_rover_outcomes(c, a) for c, a in zip(cells, actions))
    for (c1, p1), (c2, p2) in itertools.product(firsts.items(), seconds.items()):
        nxt = 64 * c1 + 16 * c2 + after
        dist[nxt] = dist.get(nxt, 0.0) + p1 * p2
    return dist


def mars_rovers() -> str:
    """The ``.dpomdp`` text of Mars rovers (module docstring)."""
    start = ["0"] * 256
    start[0] = "1"
    names = [f"site{c}{what}" for what in ("open", "done") for c in range(4)]
    out = [
        "# Mars rovers (experiments/models.py, from Amato and Zilberstein 2009)",
        "agents: 2",
        "discount: 1",
        "values: reward",
        "states: 256",
        "start:",
        " ".join(start),
        "actions:",
        "up down left right drill sample",
        "up down left right drill sample",
        "observations:",
        " ".join(names),
        " ".join(names),
    ]
    for s in range(256):
        cells, done = (s // 64, s // 16 % 4), s % 16
        for a1, a2 in itertools.product(range(6), repeat=2):
            dist = mars_next(cells, done, (a1, a2))
            out += [
                f"T: {a1} {a2} : {s} : {n} : {_number(round(p, 10))}"
                for n, p in sorted(dist.items())
            ]
            reward = mars_reward(cells, done, (a1, a2))
            if reward:
                out.append(f"R: {a1} {a2} : {s} : * : * : {_number(reward)}")
    for s in range(256):
        cells, done = (s // 64, s // 16 % 4), s % 16
        seen = [c + 4 * (done >> c & 1) for c in cells]
        out.append(f"O: * : {s} : {seen[0]} {seen[1]} : 1.0")
    return "\n".join(out) + "\n"


#: meeting in a 3 x 3 grid: action -> (row step, column step); 4 stays
GRID_MOVES = {0: (-1, 0), 1: (1, 0), 2: (0, -1), 3: (0, 1)}
GRID_MEETING_CELLS = (0, 8)
#: a move goes the intended way with this probability, each other way and nowhere with 0.1
GRID_INTENDED, GRID_ASTRAY = 0.6, 0.1


def _grid_moved(cell: int, move: tuple[int, int]) -> int:
    row, col = divmod(cell, 3)
    row, col = row + move[0], col + move[1]
    return cell if not (0 <= row < 3 and 0 <= col < 3) else 3 * row + col


def grid_outcomes(cell: int, action: int) -> dict:
    """``{next cell: probability}`` of one agent of the 3 x 3 grid (module docstring)."""
    if action not in GRID_MOVES:
        return {cell: 1.0}
    dist = {cell: GRID_ASTRAY}
    for a, move in GRID_MOVES.items():
        target = _grid_moved(cell, move)
        dist[target] = dist.get(target, 0.0) + (GRID_INTENDED if a == action else GRID_ASTRAY)
    return dist


def meeting_grid() -> str:
    """The ``.dpomdp`` text of meeting in a 3 x 3 grid with corners (module docstring)."""
    names = [f"cell{c}" for c in range(9)]
    out = [
        "# meeting in a 3 x 3 grid with corners (experiments/models.py, from Amato, Dibangoye"
        " and Zilberstein 2009)",
        "agents: 2",
        "discount: 1",
        "values: reward",
        "states: 81",
        "start: 24",
        "actions:",
        "up down left right stay",
        "up down left right stay",
        "observations:",
        " ".join(names),
        " ".join(names),
    ]
    for s in range(81):
        cells = divmod(s, 9)
        met = cells[0] == cells[1] and cells[0] in GRID_MEETING_CELLS
        for a1, a2 in itertools.product(range(5), repeat=2):
            dist: dict = {}
            firsts, seconds = grid_outcomes(cells[0], a1), grid_outcomes(cells[1], a2)
            for (c1, p1), (c2, p2) in itertools.product(firsts.items(), seconds.items()):
                dist[9 * c1 + c2] = dist.get(9 * c1 + c2, 0.0) + p1 * p2
            out += [
                f"T: {a1} {a2} : {s} : {n} : {_number(round(p, 10))}"
                for n, p in sorted(dist.items())
            ]
            if met:
                out.append(f"R: {a1} {a2} : {s} : * : * : 1")
    for s in range(81):
        c1, c2 = divmod(s, 9)
        out.append(f"O: * : {s} : {c1} {c2} : 1.0")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="model", required=True)
    ff = sub.add_parser("fire-fighting", help="fire fighting (Oliehoek et al. 2008)")
    ff.add_argument("--houses", type=int, default=3)
    ff.add_argument("--levels", type=int, default=3)
    ff.add_argument("--agents", type=int, default=2)
    ff.add_argument("--madp-rounding", action="store_true", help="two decimals, as MADP")
    ff.add_argument("--out", type=Path, required=True)
    box = sub.add_parser("box-pushing", help="cooperative box pushing (Seuken, Zilberstein 2007)")
    box.add_argument("--rules-only", action="store_true", help="without MADP's one odd line")
    box.add_argument("--out", type=Path, required=True)
    for name, what in (
        ("mars", "Mars rovers (Amato, Zilberstein 2009)"),
        ("meeting-grid", "meeting in a 3x3 grid with corners (Amato et al. 2009)"),
    ):
        sub.add_parser(name, help=what).add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    try:
        if args.model == "box-pushing":
            text = box_pushing(madp_quirk=not args.rules_only)
        elif args.model == "mars":
            text = mars_rovers()
        elif args.model == "meeting-grid":
            text = meeting_grid()
        else:
            text = fire_fighting(args.houses, args.levels, args.agents, args.madp_rounding)
    except ValueError as err:
        parser.error(str(err))
    args.out.write_text(text)
    print(f"wrote {args.out} ({len(text) / 1e6:.1f} MB)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
