"""Are the returned gains about the returned trajectory? Measured, per run.

    .venv-bench/bin/python bench/check_gains.py target/release/ilqr-service PROBLEM.json RUNS

Solves PROBLEM.json (merged over examples/seed.json, so `{"horizon": 2000}` works)
RUNS times with `BINARY solve PROBLEM -o FILE` and, for each answer,
recomputes the gains of the last knot, where the value function is the
terminal cost exactly: K = -(Q_uu + mu I)^-1 Q_ux and d = -(Q_uu + mu I)^-1
Q_u about the returned x_{N-1}, u_{N-1}, x_N, with mu the answer's
`gains.regularization`. Obstacles do not enter: their term depends on the
position only, so it adds nothing to l_u, l_uu or l_ux. Prints, per run, the
status, `gains.about_previous_iterate` and the relative errors of the
returned K and d against the recomputed ones, then a tally. Gains about the
returned trajectory match to round-off; flagged ones need not.

Needs numpy (`.venv-bench`, see bench/requirements.txt).
"""

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

SEED = json.loads((Path(__file__).resolve().parents[1] / "examples" / "seed.json").read_text())


def merge(base, over):
    out = dict(base)
    for key, value in over.items():
        nested = isinstance(value, dict) and isinstance(base.get(key), dict)
        out[key] = merge(base[key], value) if nested else value
    return out


def last_knot_gains(p, res, mu):
    """Textbook K, d at knot N-1 for the planar quadrotor under explicit Euler."""
    m, dt = p["model"], p["dt"]
    x, u, x_n = (np.array(res["states"][-2]), np.array(res["controls"][-1]), np.array(res["states"][-1]))
    s, c, thrust = np.sin(x[2]), np.cos(x[2]), u.sum()
    mass, torque = m["mass"], m["arm_length"] / m["inertia"]
    f_x = np.zeros((6, 6))
    f_x[0, 3] = f_x[1, 4] = f_x[2, 5] = 1
    f_x[3, 2], f_x[4, 2] = -thrust * c / mass, -thrust * s / mass
    f_u = np.array([[0, 0], [0, 0], [0, 0], [-s / mass, -s / mass], [c / mass, c / mass], [torque, -torque]])
    a, b = np.eye(6) + dt * f_x, dt * f_u
    w_u, w_f = np.array(p["weights"]["control"]), np.array(p["weights"]["terminal"])
    v_x, v_xx = 2 * w_f * (x_n - np.array(p["goal_state"])), np.diag(2 * w_f)
    q_u = 2 * w_u * u + b.T @ v_x
    q_uu = np.diag(2 * w_u) + b.T @ v_xx @ b
    q_ux = b.T @ v_xx @ a
    inv = np.linalg.inv(q_uu + mu * np.eye(2))
    return -inv @ q_ux, -inv @ q_u


def main():
    binary, problem_file, runs = sys.argv[1], sys.argv[2], int(sys.argv[3])
    problem = merge(SEED, json.loads(Path(problem_file).read_text()))
    tally = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "r.json"
        for _ in range(runs):
            subprocess.run([binary, "solve", problem_file, "-o", str(out)], check=True, stdout=subprocess.DEVNULL)
            res = json.loads(out.read_text())
            gains = res.get("gains")
            if gains is None:
                key = (res["status"], "no gains")
                print(res["status"], res["iterations"], "no gains")
            else:
                k, d = last_knot_gains(problem, res, gains["regularization"])
                k_err = np.abs(np.array(gains["feedback"][-1]) - k).max() / np.abs(k).max()
                d_err = np.abs(np.array(gains["feedforward"][-1]) - d).max() / max(np.abs(d).max(), 1e-300)
                key = (res["status"], "previous iterate" if gains["about_previous_iterate"] else "current")
                print(f"{res['status']} {res['iterations']} about_previous_iterate={gains['about_previous_iterate']} "
                      f"mu={gains['regularization']:.3g} K off {k_err:.2e} d off {d_err:.2e}")
            tally[key] = tally.get(key, 0) + 1
    for key, count in sorted(tally.items()):
        print(f"{count:4d}  {key[0]}, {key[1]}")


if __name__ == "__main__":
    main()
