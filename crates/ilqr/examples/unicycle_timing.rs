//! Solve Crocoddyl's unicycle problem (`ActionModelUnicycle`) with this
//! crate and time it, for `bench/crocoddyl_unicycle.py`.
//!
//! ```text
//! cargo run --release -p ilqr --example unicycle_timing -- \
//!     --horizon 100 --x0=-1,-1,1 --wx 10 --wu 1 --dt 0.1 --repeat 200
//! ```
//!
//! Crocoddyl's running cost is `½(w_x²‖x‖² + w_u²‖u‖²)` per knot and its
//! terminal cost `½w_x²‖x_N‖²`, goal the origin, explicit Euler with step
//! `dt`. In this crate's terms (no ½ factors) that is
//! `Q = Q_f = w_x²/2·I`, `R = w_u²/2·I`, goal 0.
//!
//! The initial guess is zero controls (the unicycle stands still at `x0`).
//! One `Problem` and one `Solver` are built; `--warmup` untimed solves are
//! followed by `--repeat` timed ones, each timing `Solver::solve` alone
//! (the solver reused, as the service does), with the default `Options`.
//!
//! Prints one JSON object: the cost, iterations and status of the solve,
//! the median, minimum and maximum solve time in microseconds, with
//! `--times` every timed solve's time in the order they ran, and with
//! `--trajectory` the states and controls.
//!
//! Options: `--horizon N` (100), `--dt` (0.1), `--wx` (10), `--wu` (1),
//! `--x0 a,b,c` (-1,-1,1; write `--x0=-1,-1,1` or `--x0 -1,-1,1`),
//! `--integrator euler|rk4` (euler), `--repeat` (100), `--warmup` (3),
//! `--times`, `--trajectory`.

use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use ilqr::{
    ControlEffort, Cost, DiscreteDynamics, Euler, Objective, Options, Problem, Rk4, Solver,
    StateTracking, Summary, TerminalTracking, Unicycle,
};
use nalgebra::{SVector, Vector2, Vector3};

struct Args {
    horizon: usize,
    dt: f64,
    w_x: f64,
    w_u: f64,
    x0: Vector3<f64>,
    rk4: bool,
    repeat: usize,
    warmup: usize,
    trajectory: bool,
    times: bool,
}

fn parse() -> Result<Args, String> {
    let mut a = Args {
        horizon: 100,
        dt: 0.1,
        w_x: 10.0,
        w_u: 1.0,
        x0: Vector3::new(-1.0, -1.0, 1.0),
        rk4: false,
        repeat: 100,
        warmup: 3,
        trajectory: false,
        times: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let (key, inline) = match arg.split_once('=') {
            Some((k, v)) => (k.to_string(), Some(v.to_string())),
            None => (arg.clone(), None),
        };
        match key.as_str() {
            "--trajectory" => {
                a.trajectory = true;
                continue;
            }
            "--times" => {
                a.times = true;
                continue;
            }
            _ => {}
        }
        let value = match inline {
            Some(v) => v,
            None => it.next().ok_or_else(|| format!("{key} needs a value"))?,
        };
        let number = |v: &str| {
            v.trim()
                .parse::<f64>()
                .map_err(|e| format!("{key}: {v:?}: {e}"))
        };
        let count = |v: &str| {
            v.trim()
                .parse::<usize>()
                .map_err(|e| format!("{key}: {v:?}: {e}"))
        };
        match key.as_str() {
            "--horizon" => a.horizon = count(&value)?,
            "--dt" => a.dt = number(&value)?,
            "--wx" => a.w_x = number(&value)?,
            "--wu" => a.w_u = number(&value)?,
            "--repeat" => a.repeat = count(&value)?,
            "--warmup" => a.warmup = count(&value)?,
            "--x0" => {
                let v: Vec<f64> = value.split(',').map(number).collect::<Result<_, _>>()?;
                if v.len() != 3 {
                    return Err(format!("--x0 needs 3 numbers, got {}", v.len()));
                }
                a.x0 = Vector3::from_column_slice(&v);
            }
            "--integrator" => {
                a.rk4 = match value.as_str() {
                    "euler" => false,
                    "rk4" => true,
                    other => return Err(format!("--integrator: euler or rk4, not {other:?}")),
                }
            }
            _ => return Err(format!("unknown option {key}")),
        }
    }
    if a.horizon == 0 || a.repeat == 0 {
        return Err("--horizon and --repeat must be at least 1".into());
    }
    Ok(a)
}

/// Crocoddyl's unicycle cost in this crate's terms.
fn objective(w_x: f64, w_u: f64) -> Objective<3, 2> {
    let (q, r) = (w_x * w_x / 2.0, w_u * w_u / 2.0);
    Objective::new()
        .with_stage(StateTracking {
            goal: Vector3::zeros(),
            weights: Vector3::repeat(q),
        })
        .with_stage(ControlEffort {
            weights: Vector2::repeat(r),
        })
        .with_terminal(TerminalTracking {
            goal: Vector3::zeros(),
            weights: Vector3::repeat(q),
        })
}

fn list<const N: usize>(v: &SVector<f64, N>) -> String {
    let items: Vec<String> = v.iter().map(|e| format!("{e:?}")).collect();
    format!("[{}]", items.join(","))
}

fn run<D: DiscreteDynamics<3, 2>>(a: &Args, dynamics: D) -> Result<String, String> {
    let problem = Problem {
        dynamics,
        cost: objective(a.w_x, a.w_u),
        x0: a.x0,
        horizon: a.horizon,
    };
    let guess = vec![Vector2::zeros(); a.horizon];
    let options = Options::default();
    let cancel = AtomicBool::new(false);
    let mut solver = Solver::<3, 2>::new(a.horizon);

    let solve = |solver: &mut Solver<3, 2>| -> Result<Summary, String> {
        solver
            .solve(&problem, &guess, &options, &cancel)
            .map_err(|e| e.to_string())
    };
    for _ in 0..a.warmup {
        solve(&mut solver)?;
    }
    let us = |d: Duration| d.as_secs_f64() * 1e6;
    let mut times: Vec<Duration> = Vec::with_capacity(a.repeat);
    let mut summary = None;
    for _ in 0..a.repeat {
        let t = Instant::now();
        let s = solve(&mut solver)?;
        times.push(t.elapsed());
        summary = Some(s);
    }
    let s = summary.expect("repeat is at least 1");
    let in_order: Vec<String> = times.iter().map(|&d| format!("{:?}", us(d))).collect();
    times.sort();
    let median = if times.len() % 2 == 1 {
        us(times[times.len() / 2])
    } else {
        (us(times[times.len() / 2 - 1]) + us(times[times.len() / 2])) / 2.0
    };

    // The cost recomputed from the returned trajectory, as a check on the
    // reported one.
    let xs = solver.states();
    let controls = solver.controls();
    let recomputed: f64 = (0..a.horizon)
        .map(|k| problem.cost.stage(k, &xs[k], &controls[k]))
        .sum::<f64>()
        + problem.cost.terminal(&xs[a.horizon]);

    let mut out = format!(
        "{{\"solver\":\"ilqr\",\"integrator\":\"{}\",\"horizon\":{},\"cost\":{:?},\
         \"recomputed_cost\":{:?},\"initial_cost\":{:?},\"iterations\":{},\"status\":\"{:?}\",\
         \"median_us\":{:?},\"min_us\":{:?},\"max_us\":{:?},\"repeat\":{},\"warmup\":{}",
        if a.rk4 { "rk4" } else { "euler" },
        a.horizon,
        s.cost,
        recomputed,
        s.initial_cost,
        s.iterations,
        s.status,
        median,
        us(times[0]),
        us(times[times.len() - 1]),
        a.repeat,
        a.warmup,
    );
    if a.times {
        out += &format!(",\"times_us\":[{}]", in_order.join(","));
    }
    if a.trajectory {
        let states: Vec<String> = xs.iter().map(list).collect();
        let controls: Vec<String> = controls.iter().map(list).collect();
        out += &format!(
            ",\"states\":[{}],\"controls\":[{}]",
            states.join(","),
            controls.join(",")
        );
    }
    out.push('}');
    Ok(out)
}

fn main() -> ExitCode {
    let result = parse().and_then(|a| {
        if a.rk4 {
            run(
                &a,
                Rk4 {
                    model: Unicycle,
                    dt: a.dt,
                },
            )
        } else {
            run(
                &a,
                Euler {
                    model: Unicycle,
                    dt: a.dt,
                },
            )
        }
    });
    match result {
        Ok(json) => {
            println!("{json}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("unicycle_timing: {e}");
            ExitCode::FAILURE
        }
    }
}
