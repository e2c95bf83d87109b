"""LaCAM, lazy constraints addition search (Okumura, AAAI 2023), as a plain-Python reading copy
of `mapf/lacam.py`, with this package's PIBT (`pibt.py`) as its configuration generator.

The high level is a depth-first search over configurations (one cell per robot). Each
configuration keeps a queue of low-level constraints ("robot i goes to cell v", for the
first few robots in its priority order), grown one robot deeper each time one is taken:
PIBT then generates a successor that obeys it. A configuration already seen is not
searched again. Since a configuration's constraints eventually name every successor in
full, the search is complete: it returns a plan whenever one exists, and None after it has
seen every configuration the robots can reach.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from ..types import Cell, Path, Problem
from .grid import configurations_to_paths, neighbours
from .pibt import PIBT


@dataclass
class Constraint:
    who: tuple[int, ...] = ()
    where: tuple[Cell, ...] = ()

    @property
    def depth(self) -> int:
        return len(self.who)


@dataclass
class Node:
    q: tuple[Cell, ...]
    prio: list[float]
    parent: "Node | None"
    order: list[int] = field(init=False)
    tree: deque = field(default_factory=lambda: deque([Constraint()]))

    def __post_init__(self) -> None:
        self.order = sorted(range(len(self.q)), key=lambda i: self.prio[i], reverse=True)


def lacam(problem: Problem, seed: int = 0, max_nodes: int = 1_000_000) -> list[Path] | None:
    """Paths for every robot, or None when no plan exists (every reachable configuration seen).
    RuntimeError when `max_nodes` configurations were seen first: this copy is for tiny instances."""
    generator = PIBT(problem, seed)
    starts = tuple(tuple(s) for s in problem.starts)
    goals = tuple(generator.goals)
    root = Node(starts, generator.initial_priorities(list(starts)), None)
    stack = [root]
    explored = {starts: root}
    while stack:
        node = stack[-1]
        if node.q == goals:
            return configurations_to_paths(_history(node), list(goals))
        if not node.tree:
            stack.pop()              # every successor of this configuration is generated
            continue
        c = node.tree.popleft()
        if c.depth < len(node.q):
            i = node.order[c.depth]
            options = [node.q[i]] + neighbours(generator.free, node.q[i], generator.connectivity)
            generator.rng.shuffle(options)
            node.tree.extend(Constraint(c.who + (i,), c.where + (v,)) for v in options)
        q = generator.step(node.q, node.prio, dict(zip(c.who, c.where)))
        if q is None or q in explored:
            continue
        if len(explored) >= max_nodes:
            raise RuntimeError(f"reference LaCAM: over {max_nodes} configurations")
        child = Node(q, generator.next_priorities(node.prio, q), node)
        explored[q] = child
        stack.append(child)
    return None


def _history(node: Node) -> list[tuple[Cell, ...]]:
    out = []
    while node is not None:
        out.append(node.q)
        node = node.parent
    return out[::-1]
