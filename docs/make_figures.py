#!/usr/bin/env python3
"""Regenerate the figures in docs/ from the example problems.

Each figure is made with the project's own code: the release binary solves
the problem (``ilqr-service solve PROBLEM --output RESULT.json``) and
:func:`ilqr_client.plot.save_figure` draws the result (trajectory and cost
per iteration on top, controls and θ against time below, with any bounds).

    cargo build --release
    python3 -m venv /tmp/figvenv
    /tmp/figvenv/bin/pip install -e 'clients/python[plot]'
    /tmp/figvenv/bin/python docs/make_figures.py

Environment:
    ILQR_SERVICE_BIN  the binary to run (default: target/release/ilqr-service
                      in this repository)
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib
import matplotlib.patches

matplotlib.use("Agg")  # no display needed; save_figure draws on a bare Figure anyway

from ilqr_client import Problem, SolveResult  # noqa: E402
from ilqr_client.plot import save_figure  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
DOCS = REPO / "docs"
EXAMPLES = REPO / "examples"

#: (figure written to docs/, problem in examples/)
FIGURES = [
    ("seed.png", "seed.json"),
    ("three_obstacles.png", "three_obstacles.json"),
    ("dubins_three_obstacles.png", "dubins_three_obstacles.json"),
]

DPI = 110
MAX_BYTES = 150_000


def service_binary() -> Path:
    """The ilqr-service binary: $ILQR_SERVICE_BIN, else the release build of this repository."""
    configured = os.environ.get("ILQR_SERVICE_BIN")
    binary = Path(configured) if configured else REPO / "target" / "release" / "ilqr-service"
    if not binary.is_file():
        sys.exit(f"error: {binary} not found: run `cargo build --release` or set ILQR_SERVICE_BIN")
    return binary


def solve(binary: Path, problem_path: Path, workdir: Path) -> SolveResult:
    """Solve a problem file with the CLI and parse the full result JSON it writes."""
    result_path = workdir / (problem_path.stem + ".result.json")
    run = subprocess.run(
        [str(binary), "solve", str(problem_path), "--output", str(result_path)],
        capture_output=True, text=True,
    )
    if run.returncode != 0:
        sys.exit(f"error: {binary.name} solve {problem_path} failed ({run.returncode}):\n{run.stderr}")
    print(run.stdout, end="")
    return SolveResult.from_dict(json.loads(result_path.read_text()))


def routes_figure(binary: Path, workdir: Path) -> None:
    """docs/routes.png: the seed's two routes, the paper's single solve from
    hover (``multi_start: false``, west) and the search's answer (east),
    with the straight path the detours are placed about."""
    from matplotlib.figure import Figure

    seed = json.loads((EXAMPLES / "seed.json").read_text())
    results = {}
    for name, multi in (("single", False), ("search", True)):
        path = workdir / f"routes-{name}.json"
        path.write_text(json.dumps(dict(seed, solver=dict(seed.get("solver", {}), multi_start=multi))))
        results[name] = solve(binary, path, workdir)
    problem = Problem.from_dict(seed)
    fig = Figure(figsize=(5.2, 5.6))
    ax = fig.add_subplot()
    start, goal = results["search"].states[0], problem.goal_state or [4.0, 9.0]
    ax.plot([start[0], goal[0]], [start[1], goal[1]], ":", color="0.6", label="straight path")
    for o in problem.obstacles or []:
        for r, alpha in ((1.0, 0.25), (2.0, 0.15), (3.0, 0.08)):
            ax.add_patch(matplotlib.patches.Circle(o.center, r, color="tab:red", alpha=alpha, lw=0))
        ax.plot(*o.center, "x", color="tab:red")
    chosen = next(s for s in results["search"].starts if s.chosen)
    for name, color, text in (
        ("single", "tab:gray", f"single solve from hover (paper): {results['single'].cost:.3f}"),
        ("search", "tab:blue", f"search, {chosen.label}: {results['search'].cost:.3f}"),
    ):
        xs = [x[0] for x in results[name].states]
        ys = [x[1] for x in results[name].states]
        ax.plot(xs, ys, "-", color=color, lw=2, label=text)
    ax.plot(*start[:2], "o", color="k")
    ax.plot(goal[0], goal[1], "*", color="k", ms=12)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("The seed's two routes around the obstacle")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), fontsize=8)
    out = DOCS / "routes.png"
    fig.savefig(out, dpi=DPI, bbox_inches="tight")
    print(f"wrote {out.relative_to(REPO)} ({out.stat().st_size / 1000:.0f} kB)")


def main() -> int:
    binary = service_binary()
    with tempfile.TemporaryDirectory(prefix="ilqr-figures-") as tmp:
        routes_figure(binary, Path(tmp))
        for figure_name, problem_name in FIGURES:
            problem_path = EXAMPLES / problem_name
            print(f"--- {problem_path.relative_to(REPO)}")
            result = solve(binary, problem_path, Path(tmp))
            problem = Problem.from_dict(json.loads(problem_path.read_text()))
            out = DOCS / figure_name
            save_figure(result, problem, out, dpi=DPI)
            size = out.stat().st_size
            print(f"wrote {out.relative_to(REPO)} ({size / 1000:.0f} kB)")
            if size > MAX_BYTES:
                print(f"warning: {out.name} is larger than {MAX_BYTES / 1000:.0f} kB", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
