"""report.html: a mission's report for people, one self-contained file (inline SVG, no external asset).

The summary, robots on their goals per tick, planned against executed (makespan, sum of costs, each
robot's deviation), the phases' timing bar and, on a floor with people, forklifts or pallets, the movers
and the robots' contacts with them, all computed from the mission's report (report.json with details.json
and plan.json).
"""
from __future__ import annotations

import html
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .recording import mover_kinds

REPORT_HTML = "report.html"
PHASE_COLOURS = ["#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7",
                 "#9c755f", "#bab0ac", "#86bcb6", "#d37295"]


def arrival(cells: list) -> int:
    """The tick a robot reached the cell it kept to the end (0 if it never moved)."""
    last = cells[-1] if cells else None
    t = len(cells) - 1
    while t > 0 and cells[t - 1] == last:
        t -= 1
    return max(t, 0)


@dataclass(frozen=True)
class Comparison:
    robot: int
    planned: int          # ticks to the goal in the first plan
    executed: int         # ticks to the cell the robot ended on
    on_goal: bool

    @property
    def deviation(self) -> int:
        return self.executed - self.planned


def compare(report: dict[str, Any]) -> list[Comparison]:
    plan = {r["id"]: r for r in (report.get("plan") or {}).get("robots", [])}
    out = []
    for key, cells in sorted(report.get("executed", {}).items(), key=lambda kv: int(kv[0])):
        rid = int(key)
        p = plan.get(rid, {})
        planned = p.get("cost", arrival(p.get("path", [])))
        out.append(Comparison(rid, planned, arrival(cells), bool(cells) and list(cells[-1]) == list(p.get("goal", []))))
    return out


def arrived_per_tick(report: dict[str, Any]) -> list[int]:
    """How many robots stood on their goal, to stay, at each tick."""
    rows = compare(report)
    ticks = max([len(c) - 1 for c in report.get("executed", {}).values()] + [report.get("ticks", 0), 0])
    return [sum(1 for c in rows if c.on_goal and c.executed <= t) for t in range(ticks + 1)]


def _esc(v: Any) -> str:
    return html.escape(str(v))


def _arrivals_svg(counts: list[int], robots: int, w: int = 640, h: int = 220) -> str:
    m = 36
    n = max(1, len(counts) - 1)
    top = max(1, robots)
    pts = " ".join(f"{m + i * (w - 2 * m) / n:.1f},{h - m - c * (h - 2 * m) / top:.1f}" for i, c in enumerate(counts))
    return (f'<svg width="{w}" height="{h}" role="img" aria-label="robots on their goals per tick">'
            f'<line x1="{m}" y1="{h - m}" x2="{w - m}" y2="{h - m}" stroke="#333"/>'
            f'<line x1="{m}" y1="{m}" x2="{m}" y2="{h - m}" stroke="#333"/>'
            f'<polyline fill="none" stroke="#4e79a7" stroke-width="2" points="{pts}"/>'
            f'<text x="{m}" y="{m - 8}" font-size="12">{top} robots</text>'
            f'<text x="{w - m}" y="{h - 10}" font-size="12" text-anchor="end">tick {len(counts) - 1}</text>'
            f'<text x="{m}" y="{h - 10}" font-size="12">0</text></svg>')


def _timing_svg(timings: dict[str, float], w: int = 640) -> str:
    phases = [(k, v) for k, v in timings.items() if k != "wall_total" and v > 0]
    total = sum(v for _, v in phases) or 1.0
    x, bars, keys = 0.0, [], []
    for i, (name, v) in enumerate(phases):
        col = PHASE_COLOURS[i % len(PHASE_COLOURS)]
        width = v / total * w
        bars.append(f'<rect x="{x:.1f}" y="0" width="{width:.1f}" height="28" fill="{col}">'
                    f'<title>{_esc(name)} {v:.2f} s</title></rect>')
        keys.append(f'<span style="color:{col}">&#9632;</span> {_esc(name)} {v:.2f} s')
        x += width
    return (f'<svg width="{w}" height="28" role="img" aria-label="phase timings">{"".join(bars)}</svg>'
            f'<p class="keys">{" &nbsp; ".join(keys)}</p>')


def _movers_section(report: dict[str, Any]) -> str:
    """The floor's movers: how many of each kind, robot-mover collisions and near misses, each contact; nothing
    on a floor without movers (report.json then has no `movers`)."""
    if not report.get("movers"):
        return ""
    truth = (report.get("truth") or {}).get("movers") or {}
    kinds = mover_kinds(str(m.get("kind", "?")) for m in truth.get("movers", []))
    rows = [("movers on the floor", f"{report['movers']}" + (f" ({kinds})" if kinds else "")),
            ("robot-mover collisions", report.get("mover_collisions", 0)),
            ("near misses (a robot within one cell of a mover)", report.get("near_misses", 0)),
            ("ticks with a robot near a mover (robot-mover pairs)", report.get("near_miss_ticks", 0))]
    table = "".join(f"<tr><th>{_esc(k)}</th><td>{_esc(v)}</td></tr>" for k, v in rows)
    contacts = "".join("<tr>" + "".join(f"<td>{_esc(v)}</td>" for v in (
                           c.get("tick"), c.get("robot"), c.get("mover"), ", ".join(map(str, c.get("cell") or [])),
                           c.get("how"))) + "</tr>" for c in truth.get("contacts", []))
    return ("<h2>People, forklifts and pallets</h2>\n"
            f'<table id="movers">{table}</table>\n'
            + (f'<p>Robot-mover contacts, as the world judged them:</p>\n<table id="mover-contacts"><tr><th>tick</th>'
               f"<th>robot</th><th>mover</th><th>cell</th><th>how</th></tr>{contacts}</table>\n" if contacts else ""))


def render(report: dict[str, Any]) -> str:
    rows = compare(report)
    metrics = (report.get("plan") or {}).get("metrics", {})
    ex_soc, ex_make = sum(c.executed for c in rows), max((c.executed for c in rows), default=0)
    verified = report.get("verified", {})
    summary = [("outcome", report.get("outcome", "")), ("reason", report.get("reason", "")),
               ("robots", report.get("robots", "")),
               ("verified on their goals", sum(1 for v in verified.values() if v)),
               ("ticks", report.get("ticks", "")), ("collisions", report.get("collisions", "")),
               ("replans", report.get("replans", 0)), ("out of the plan", report.get("lost", [])),
               ("unserved goals", report.get("unserved_goals", [])),
               ("planner", (report.get("plan") or {}).get("planner", ""))]
    table = "".join(f"<tr><th>{_esc(k)}</th><td>{_esc(v)}</td></tr>" for k, v in summary)
    deviating = [c for c in rows if c.deviation or not c.on_goal]
    dev_rows = "".join(f"<tr><td>{c.robot}</td><td>{c.planned}</td><td>{c.executed}</td><td>{c.deviation:+d}</td>"
                       f"<td>{'yes' if c.on_goal else 'no'}</td></tr>" for c in deviating)
    events = "".join(f"<tr><td>{_esc(e['tick'])}</td><td>{_esc(e['kind'])}</td><td>{_esc(e['robots'])}</td>"
                     f"<td>{_esc(e['what'])}</td><td>{_esc(e.get('action', ''))}</td></tr>"
                     for e in report.get("events", []))
    wall = report.get("timings", {}).get("wall_total")
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>uav-robots mission: {_esc(report.get('outcome', ''))}</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:720px}} table{{border-collapse:collapse}}
th,td{{border:1px solid #ccc;padding:3px 8px;text-align:left}} .keys{{font-size:13px}}</style></head><body>
<h1>Mission {_esc(report.get('outcome', '')).upper()}</h1>
<table id="summary">{table}</table>
<h2>Robots on their goals per tick</h2>
{_arrivals_svg(arrived_per_tick(report), len(rows) or int(report.get('robots', 0)))}
<h2>Planned and executed</h2>
<table id="planned-executed"><tr><th></th><th>planned</th><th>executed</th></tr>
<tr><th>makespan</th><td>{_esc(metrics.get('makespan', ''))}</td><td>{ex_make}</td></tr>
<tr><th>sum of costs</th><td>{_esc(metrics.get('sum_of_costs', ''))}</td><td>{ex_soc}</td></tr>
<tr><th>lower bound</th><td>{_esc(metrics.get('lower_bound', ''))}</td><td></td></tr></table>
<p>{len(deviating)} of {len(rows)} robots arrived at another tick than planned, or elsewhere:</p>
<table id="deviations"><tr><th>robot</th><th>planned ticks</th><th>executed ticks</th><th>deviation</th>
<th>on its goal</th></tr>{dev_rows}</table>
<h2>Time per phase</h2>
{_timing_svg(report.get('timings', {}))}
{f'<p>whole run: {wall:.2f} s wall</p>' if wall else ''}
{_movers_section(report)}<h2>Events</h2>
<table id="events"><tr><th>tick</th><th>kind</th><th>robots</th><th>what</th><th>action</th></tr>{events}</table>
</body></html>
"""


def write(out: Path, report: dict[str, Any]) -> Path:
    from ..common.outputs import write_atomic

    path = out / REPORT_HTML
    write_atomic(path, render(report))
    return path
