//! `solve::solve` keeps each thread's solver workspace for its next solve;
//! nothing of one solve may leak into the next. And the wire JSON written
//! into a pre-sized buffer is the result, whole.

use std::sync::atomic::AtomicBool;

use ilqr_service::problem::{ProblemSpec, parse};
use ilqr_service::solve::{Rows, SolveResult, solve};
use serde_json::json;

fn spec(doc: serde_json::Value) -> ProblemSpec {
    let spec = parse(doc.to_string().as_bytes()).unwrap();
    spec.validate(&Default::default()).unwrap();
    spec
}

/// The result without its wall-clock fields, which differ run to run.
fn timeless(mut r: SolveResult) -> SolveResult {
    r.solve_time_ms = 0.0;
    for row in r.trace.iter_mut().flatten() {
        row.elapsed_ms = 0.0;
    }
    for start in &mut r.starts {
        start.solve_time_ms = 0.0;
    }
    r
}

fn solve_on(thread_specs: Vec<ProblemSpec>) -> Vec<SolveResult> {
    std::thread::spawn(move || {
        let cancel = AtomicBool::new(false);
        thread_specs
            .iter()
            .map(|s| timeless(solve(s, None, &cancel).unwrap()))
            .collect()
    })
    .join()
    .unwrap()
}

#[test]
fn a_reused_workspace_gives_the_answers_of_a_fresh_one() {
    let problems = vec![
        spec(json!({})),
        // Shorter, other obstacles, its own initial controls: every buffer
        // shrinks and holds the previous solve's numbers past the horizon.
        spec(json!({
            "horizon": 40,
            "dt": 0.1,
            "obstacles": [{"center": [4.8, 2.0], "weight": 500}, {"center": [4.0, 6.0], "weight": 800}],
            "initial_controls": vec![[5.0, 5.2]; 40],
        })),
        // Longer than the cached size: solved on a workspace of its own.
        spec(json!({"horizon": 1200, "dt": 0.005, "solver": {"max_iterations": 30}})),
        // A solve stopped by max_iterations leaves gains and trace of an
        // unfinished solve in the workspace.
        spec(json!({"solver": {"max_iterations": 3}})),
        spec(json!({})),
    ];
    // Every problem on a thread of its own: a fresh workspace each.
    let fresh: Vec<SolveResult> = problems
        .iter()
        .map(|p| solve_on(vec![p.clone()]).remove(0))
        .collect();
    // All of them in a row on one thread, then again in reverse.
    let reused = solve_on(problems.clone());
    let reversed = solve_on(problems.iter().rev().cloned().collect());
    for (i, f) in fresh.iter().enumerate() {
        assert_eq!(&reused[i], f, "problem {i} after {i} others");
        assert_eq!(
            &reversed[problems.len() - 1 - i],
            f,
            "problem {i}, reversed"
        );
    }
    assert_eq!(fresh[0], fresh[4]);
    assert_eq!(fresh[3].iterations, 3);
}

#[test]
fn the_wire_json_is_the_whole_result() {
    let cancel = AtomicBool::new(false);
    for doc in [
        json!({}),
        json!({"output": {"gains": false, "trace": false}}),
        json!({"horizon": 1000, "dt": 0.005}),
    ] {
        let r = solve(&spec(doc.clone()), None, &cancel).unwrap();
        let bytes = r.to_json().unwrap();
        assert_eq!(bytes, serde_json::to_vec(&r).unwrap(), "{doc}");
        let back: SolveResult = serde_json::from_slice(&bytes).unwrap();
        assert_eq!(back, r, "{doc}");
    }
}

#[test]
fn a_result_posted_back_as_a_warm_start_rolls_out_to_its_own_cost() {
    // Every number of the answer survives JSON both ways: parsed back by the
    // same parser the service uses, the controls roll out to the same states
    // and so to the same cost, bit for bit.
    // The second problem's thrusts pass 1e6 N, which `initial_controls`
    // takes back: its bound is far above any control a valid problem needs.
    let cancel = AtomicBool::new(false);
    let heavy = json!({"model": {"mass": 3e5}, "weights": {"control": [1e-9, 1e-9]}});
    for (problem, thrusts_above) in [(json!({}), 0.0), (heavy, 1e6)] {
        let first = solve(&spec(problem.clone()), None, &cancel).unwrap();
        let largest = first
            .controls
            .iter()
            .flatten()
            .fold(0.0f64, |m, u| m.max(u.abs()));
        assert!(largest > thrusts_above, "{largest}");
        let wire: serde_json::Value = serde_json::from_slice(&first.to_json().unwrap()).unwrap();
        let mut warm = problem;
        warm["initial_controls"] = wire["controls"].clone();
        warm["solver"] = json!({"max_iterations": 1});
        let again = solve(&spec(warm), None, &cancel).unwrap();
        assert_eq!(again.initial_cost.to_bits(), first.cost.to_bits());
        assert!(again.cost <= first.cost);
    }
}

/// A solve whose first backward pass never completes has no policy: one
/// cancelled before it starts (the flag already set; N = 1000, so the
/// first linearisation polls it, at knot 128) ends during its first
/// linearisation, and the answer (`cancelled`, 0 iterations, the initial guess)
/// leaves the gains out rather than sending zeros that read as an
/// open-loop policy. A solve with even one complete pass keeps them,
/// `max_iterations: 0` included.
#[test]
fn gains_are_left_out_when_no_backward_pass_completed() {
    let cancelled = AtomicBool::new(true);
    let r = solve(&spec(json!({"horizon": 1000})), None, &cancelled).unwrap();
    assert_eq!(
        (r.status.as_str(), r.iterations, r.cost),
        ("cancelled", 0, r.initial_cost)
    );
    assert!(r.gains.is_none());
    let wire: serde_json::Value = serde_json::from_slice(&r.to_json().unwrap()).unwrap();
    assert!(wire.get("gains").is_none(), "{wire}");

    let cancel = AtomicBool::new(false);
    let r = solve(
        &spec(json!({"solver": {"max_iterations": 0}})),
        None,
        &cancel,
    )
    .unwrap();
    assert_eq!((r.status.as_str(), r.iterations), ("max_iterations", 0));
    let gains = r.gains.expect("one backward pass completed");
    assert!(
        gains
            .feedback
            .iter()
            .any(|k| k.flat().iter().any(|v| *v != 0.0))
    );
}

/// `gains.regularization` is on the wire and says how the gains were
/// damped: 0 for the seed (undamped Riccati gains about its optimum); the
/// three-obstacle example's single solve stops with μ > 0, and its gains
/// say so. That they
/// are exactly the gains of that μ is checked in the core's tests.
#[test]
fn gains_report_the_regularization_they_were_built_with() {
    let cancel = AtomicBool::new(false);
    let seed = solve(&spec(json!({})), None, &cancel).unwrap();
    assert_eq!(seed.status.as_str(), "converged");
    let seed_gains = seed.gains.expect("seed gains");
    assert_eq!(seed_gains.regularization, 0.0);
    assert!(!seed_gains.about_previous_iterate);

    let example = std::fs::read("examples/three_obstacles.json").unwrap();
    let mut three = parse(&example).unwrap();
    // Its single local solve (the search's best route converges undamped).
    three.solver.multi_start = Some(false);
    let r = solve(&three, None, &cancel).unwrap();
    let mu = r.gains.as_ref().expect("gains").regularization;
    assert!(mu > 0.0 && mu.is_finite(), "{mu}");
    let wire: serde_json::Value = serde_json::to_value(&r).unwrap();
    assert_eq!(
        wire["gains"]["regularization"],
        json!(mu),
        "{}",
        wire["gains"]["regularization"]
    );
    assert_eq!(wire["gains"]["about_previous_iterate"], json!(false));
}

/// `solve -o -` puts the result JSON alone on standard output (so it pipes
/// into jq) and the human summary on standard error; a bad problem is an
/// error naming the field, with exit status 2.
#[test]
fn the_cli_writes_clean_json_to_stdout_with_output_dash() {
    use std::io::Write;
    use std::process::{Command, Stdio};
    let run = |input: &str| {
        let mut child = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
            .args(["solve", "-", "-o", "-"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        child
            .stdin
            .take()
            .unwrap()
            .write_all(input.as_bytes())
            .unwrap();
        child.wait_with_output().unwrap()
    };
    let ok = run(r#"{"output": {"trace": false}}"#);
    assert!(ok.status.success());
    let result: serde_json::Value = serde_json::from_slice(&ok.stdout).unwrap();
    assert_eq!(result["status"], "converged");
    let summary = String::from_utf8(ok.stderr).unwrap();
    assert!(
        summary.starts_with("model            quadrotor_2d (euler)\nstatus           converged"),
        "{summary}"
    );

    let bad = run(r#"{"dt": 1e300}"#);
    assert_eq!(bad.status.code(), Some(2));
    assert!(bad.stdout.is_empty());
    assert_eq!(
        String::from_utf8(bad.stderr).unwrap(),
        "error: /dt: must be a positive number of seconds, at most 10, got 1e300\n"
    );

    // A wrong type and an out-of-range value: one line each.
    let both = run(r#"{"dt": "x", "horizon": 0}"#);
    assert_eq!(both.status.code(), Some(2));
    assert_eq!(
        String::from_utf8(both.stderr).unwrap(),
        "error: /dt: invalid type: string \"x\", expected a number\n\
         error: /horizon: must be an integer from 1 to 10000, got 0\n"
    );

    // Past the 100 listed errors, one line counts the rest.
    let rows = vec!["[1e13, 1e13]"; 5000].join(",");
    let flood = run(&format!(
        r#"{{"horizon": 5000, "initial_controls": [{rows}]}}"#
    ));
    assert_eq!(flood.status.code(), Some(2));
    let stderr = String::from_utf8(flood.stderr).unwrap();
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 101, "{stderr}");
    assert!(lines[0].contains("/initial_controls/0/0"), "{stderr}");
    assert_eq!(
        lines[100],
        "error: 9900 more invalid values not listed (only the first 100 are)"
    );
}

/// A problem that is not JSON names its source, as a read error does: the
/// line and column alone do not say which of a script's files it was.
#[test]
fn the_cli_names_the_file_that_is_not_json() {
    use std::process::Command;
    let path = std::env::temp_dir().join(format!("ilqr-cli-syntax-{}.json", std::process::id()));
    std::fs::write(&path, "{\"dt\": }").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .arg("solve")
        .arg(&path)
        .output()
        .unwrap();
    std::fs::remove_file(&path).unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(
        String::from_utf8(out.stderr).unwrap(),
        format!(
            "error: {} is not valid JSON: expected value at line 1 column 8\n",
            path.display()
        )
    );
    let out = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .args(["solve", "-"])
        .stdin(std::fs::File::open("/dev/null").unwrap())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(
        String::from_utf8(out.stderr).unwrap(),
        "error: standard input is not valid JSON: EOF while parsing a value at line 1 column 0\n"
    );
}

/// A reader that closes standard output before the answer is written
/// (`solve -o - | head`) ends the command quietly with exit code 0, as a Unix
/// filter does, not with "error: cannot write -: Broken pipe" and exit code 1
/// (nor, without `-o`, with a panic in the summary's `print!`). The pipe is
/// closed before the command starts, so it is closed at every write.
#[test]
fn a_closed_stdout_pipe_ends_the_cli_quietly() {
    use std::process::Command;
    for args in [
        &["solve", "examples/seed.json"][..],
        &["solve", "examples/seed.json", "-o", "-"],
        &["solve", "examples/seed.json", "-o", "/dev/stdout"],
    ] {
        let (reader, writer) = std::io::pipe().unwrap();
        drop(reader);
        let out = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
            .args(args)
            .stdout(writer)
            .output()
            .unwrap();
        let stderr = String::from_utf8(out.stderr).unwrap();
        assert_eq!(out.status.code(), Some(0), "{args:?}: {stderr}");
        assert!(!stderr.contains("error"), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    }
    // The output file is still written when only the summary's reader left.
    let path = std::env::temp_dir().join(format!("ilqr-cli-pipe-{}.json", std::process::id()));
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
        .args(["solve", "examples/seed.json", "-o"])
        .arg(&path)
        .stdout(writer)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{out:?}");
    let written: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    std::fs::remove_file(&path).unwrap();
    assert_eq!(written["status"], "converged");
}

/// `-o FILE` is checked before the solve but written only after it: an
/// unwritable path fails at once, an invalid problem leaves an existing file as it was and creates none, a
/// solve killed midway leaves nothing behind (through a dangling symlink
/// neither), and devices and pipes (`/dev/null`, `/dev/stdout` into a pipe
/// or a file opened for appending, a named pipe) take the JSON.
#[test]
fn the_cli_output_file_is_written_only_with_a_result() {
    use std::process::{Command, Stdio};
    let dir = std::env::temp_dir().join(format!("ilqr-cli-out-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bin = env!("CARGO_BIN_EXE_ilqr-service");
    let problem = |name: &str, doc: &str| {
        let path = dir.join(name);
        std::fs::write(&path, doc).unwrap();
        path
    };
    let bad = problem("bad.json", r#"{"dt": -1}"#);
    // `solve [PROBLEM] -o OUT`, standard output captured.
    let solve_to = |input: Option<&std::path::Path>, out: &std::path::Path| {
        let mut cmd = Command::new(bin);
        cmd.arg("solve");
        cmd.args(input);
        cmd.arg("-o")
            .arg(out)
            .stdout(Stdio::piped())
            .output()
            .unwrap()
    };
    let succeeded = |out: &std::process::Output| {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    };

    // An unwritable output fails before the solve (no summary printed).
    let unwritable = solve_to(None, "/nonexistent-dir/r.json".as_ref());
    assert_eq!(unwritable.status.code(), Some(1));
    assert!(unwritable.stdout.is_empty(), "solved first");
    assert!(
        String::from_utf8(unwritable.stderr)
            .unwrap()
            .starts_with("error: cannot write /nonexistent-dir/r.json: "),
    );

    // A problem that cannot be read (missing, a directory) is not an
    // invalid problem: exit 1, not 2, so that a script can tell them apart.
    for input in [dir.join("missing.json"), dir.clone()] {
        let unreadable = solve_to(Some(&input), &dir.join("never.json"));
        let stderr = String::from_utf8(unreadable.stderr).unwrap();
        assert_eq!(unreadable.status.code(), Some(1), "{input:?}: {stderr}");
        assert!(
            stderr.starts_with(&format!("error: cannot read {}: ", input.display())),
            "{stderr}"
        );
        assert!(!dir.join("never.json").exists());
    }

    // Invalid problem: an existing output keeps its content, a new one is
    // not created.
    let existing = dir.join("existing.json");
    std::fs::write(&existing, "keep me").unwrap();
    assert_eq!(solve_to(Some(&bad), &existing).status.code(), Some(2));
    assert_eq!(std::fs::read_to_string(&existing).unwrap(), "keep me");
    let fresh = dir.join("fresh.json");
    assert_eq!(solve_to(Some(&bad), &fresh).status.code(), Some(2));
    assert!(!fresh.exists(), "an invalid problem left {fresh:?}");

    // A valid one overwrites the existing file with the whole result.
    succeeded(&solve_to(None, &existing));
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&existing).unwrap()).unwrap();
    assert_eq!(written["status"], "converged");

    // Devices: /dev/null swallows it, /dev/stdout carries it into a pipe.
    succeeded(&solve_to(None, "/dev/null".as_ref()));
    let out = solve_to(None, "/dev/stdout".as_ref());
    succeeded(&out);
    let stdout = String::from_utf8(out.stdout).unwrap();
    let json_start = stdout.find("{\n").expect("the JSON follows the summary");
    let piped: serde_json::Value = serde_json::from_str(&stdout[json_start..]).unwrap();
    assert_eq!(piped["status"], "converged");

    // /dev/stdout redirected to a file opened for appending: what was there,
    // the summary and the JSON all stay, in that order (no truncation).
    let log = dir.join("log.txt");
    std::fs::write(&log, "earlier line\n").unwrap();
    let appending = std::fs::OpenOptions::new().append(true).open(&log).unwrap();
    let status = Command::new(bin)
        .args(["solve", "-o", "/dev/stdout"])
        .stdout(appending)
        .status()
        .unwrap();
    assert!(status.success());
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(
        text.starts_with(
            "earlier line\nmodel            quadrotor_2d (euler)\nstatus           converged"
        ),
        "{text}"
    );
    let appended: serde_json::Value =
        serde_json::from_str(&text[text.find("{\n").unwrap()..]).unwrap();
    assert_eq!(appended["status"], "converged");

    // A named pipe with one reader gets the JSON: the check before the solve
    // must not close the pipe, or the reader sees the end of its input and
    // the write after the solve blocks for ever. Bounded, so that a
    // regression fails instead of hanging.
    let fifo = dir.join("fifo");
    assert!(
        Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read_to_string(fifo).unwrap())
    };
    let mut child = Command::new(bin)
        .args(["solve", "-o"])
        .arg(&fifo)
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if std::time::Instant::now() > deadline {
            child.kill().unwrap();
            // Unblock the reader thread, then fail.
            let _ = std::fs::OpenOptions::new().write(true).open(&fifo);
            panic!("solve -o FIFO hung");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    assert!(status.success());
    let through_fifo: serde_json::Value = serde_json::from_str(&reader.join().unwrap()).unwrap();
    assert_eq!(through_fifo["status"], "converged");

    // A dangling symlink: written through, the link kept; an invalid
    // problem neither replaces the link nor creates its target.
    let link = dir.join("link.json");
    let link_target = dir.join("link-target.json");
    std::os::unix::fs::symlink(&link_target, &link).unwrap();
    let is_link = |p: &std::path::Path| p.symlink_metadata().unwrap().file_type().is_symlink();
    assert_eq!(solve_to(Some(&bad), &link).status.code(), Some(2));
    assert!(is_link(&link) && !link_target.exists());
    succeeded(&solve_to(None, &link));
    assert!(is_link(&link));
    let through_link: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&link_target).unwrap()).unwrap();
    assert_eq!(through_link["status"], "converged");

    // A long solve to kill (about 2.5 s: N = 10000, 100 obstacles).
    let obstacles: Vec<_> = (0..100)
        .map(
            |i| json!({"center": [f64::from(i % 10) - 2.5, f64::from(i / 10) - 0.5], "weight": 10}),
        )
        .collect();
    let long = problem(
        "long.json",
        &json!({"horizon": 10000, "dt": 0.0005, "obstacles": obstacles,
                "solver": {"tolerance": 0, "max_iterations": 10000}})
        .to_string(),
    );
    // Killed: neither a new file nor, through a dangling link, its target.
    let dangling = dir.join("dangling.json");
    let dangling_target = dir.join("dangling-target.json");
    std::os::unix::fs::symlink(&dangling_target, &dangling).unwrap();
    let killed = dir.join("killed.json");
    for out in [&killed, &dangling] {
        let mut child = Command::new(bin)
            .arg("solve")
            .arg(&long)
            .arg("-o")
            .arg(out)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(300));
        assert!(
            child.try_wait().unwrap().is_none(),
            "the long solve ended early"
        );
        child.kill().unwrap();
        child.wait().unwrap();
    }
    assert!(!killed.exists(), "a killed solve left {killed:?}");
    assert!(is_link(&dangling) && !dangling_target.exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `closest_approach` measures the path between the states, not only the
/// states: at `dt = 1` the seed's path cuts between two knots that are both
/// 3.4 m from the obstacle centre, passing 0.2 m from it. Checked against
/// 10 000 points sampled along every segment.
#[test]
fn closest_approach_measures_the_path_between_the_states() {
    let cancel = AtomicBool::new(false);
    for doc in [
        json!({"dt": 1, "horizon": 10}),
        json!({}),
        json!({"obstacles": [{"center": [4.5, 4.5], "weight": 1000}, {"center": [5, 0], "weight": 1}]}),
    ] {
        let s = spec(doc.clone());
        let r = solve(&s, None, &cancel).unwrap();
        for (o, &reported) in s.obstacles.iter().zip(&r.closest_approach) {
            let dist = |p: [f64; 2]| (p[0] - o.center[0]).hypot(p[1] - o.center[1]);
            let at_knots = r
                .states
                .iter()
                .map(|x| dist([x[0], x[1]]))
                .fold(f64::INFINITY, f64::min);
            let states: Vec<&[f64]> = r.states.iter().collect();
            let sampled = states
                .windows(2)
                .flat_map(|w| {
                    (0..=10_000).map(move |i| {
                        let t = f64::from(i) / 10_000.0;
                        [
                            w[0][0] + t * (w[1][0] - w[0][0]),
                            w[0][1] + t * (w[1][1] - w[0][1]),
                        ]
                    })
                })
                .map(dist)
                .fold(f64::INFINITY, f64::min);
            assert!(reported <= at_knots, "{doc}: {reported} > {at_knots}");
            // Sampling can only overestimate, by at most half a sample step.
            let step = states
                .windows(2)
                .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]) / 10_000.0)
                .fold(0.0, f64::max);
            assert!(
                reported <= sampled && sampled - reported <= step,
                "{doc}: reported {reported}, sampled {sampled} (step {step})"
            );
        }
    }
    let coarse = solve(&spec(json!({"dt": 1, "horizon": 10})), None, &cancel).unwrap();
    assert!(
        coarse.closest_approach[0] < 0.5,
        "{:?}",
        coarse.closest_approach
    );
}

/// A guess held on an obstacle's tip has no descent direction: every trial's
/// model reduction is zero, and the trace says 0, not -0.
#[test]
fn a_zero_model_reduction_is_written_as_zero_not_minus_zero() {
    let cancel = AtomicBool::new(false);
    let tip = spec(json!({
        "initial_state": [4.5, 4.5, 0, 0, 0, 0],
        "goal_state": [4.5, 4.5, 0, 0, 0, 0],
        "model": {"gravity": 0},
        "initial_controls": vec![[0, 0]; 100],
    }));
    let r = solve(&tip, None, &cancel).unwrap();
    assert_eq!(r.status.as_str(), "no_progress");
    let wire = String::from_utf8(r.to_json().unwrap()).unwrap();
    let rows = wire.matches("\"expected_reduction\":0.0").count();
    assert!(rows > 0, "{wire}");
    assert!(!wire.contains("\"expected_reduction\":-0.0"), "{wire}");
}

/// The summary's values start in one column, obstacle 10 and on included;
/// past ten obstacles it lists the nearest ten, in index order, and counts
/// the rest.
#[test]
fn the_summary_keeps_its_column_past_nine_obstacles() {
    let cancel = AtomicBool::new(false);
    // Obstacle i at (4.5, 32 − i): the higher the index, the nearer.
    let obstacles: Vec<_> = (0..12)
        .map(|i| json!({"center": [4.5, 32 - i], "weight": 1}))
        .collect();
    let p = spec(json!({"obstacles": obstacles, "solver": {"max_iterations": 2}}));
    let r = solve(&p, None, &cancel).unwrap();
    let text = ilqr_service::cli::summary(&p, &r);
    for line in text.lines() {
        assert!(
            !line[..17].ends_with(|c: char| !c.is_whitespace()),
            "{line}"
        );
        assert!(!line[17..].starts_with(' '), "{line}");
    }
    assert!(
        text.contains("\nobstacle 2       closest approach"),
        "{text}"
    );
    assert!(
        text.contains("\nobstacle 11      closest approach"),
        "{text}"
    );
    assert!(!text.contains("obstacle 1 "), "{text}");
    let more = format!(
        "\n{:17}2 more, none nearer than {:.4} m",
        "", r.closest_approach[1]
    );
    assert!(text.contains(&more), "{text}");
    let listed: Vec<&str> = text.lines().filter(|l| l.starts_with("obstacle")).collect();
    assert_eq!(listed.len(), 10, "{text}");
}

/// Ctrl-C during `solve` stops it like a cancelled request: the best
/// trajectory so far is printed and written, with status `cancelled`, and
/// the exit code is 128 + the signal's number, as for an interrupted
/// command (130 for SIGINT, 143 for SIGTERM).
#[test]
fn an_interrupted_cli_solve_writes_its_best_trajectory() {
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    let dir = std::env::temp_dir().join(format!("ilqr-cli-sigint-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (problem, out) = (dir.join("p.json"), dir.join("r.json"));
    // Minutes of work: N = 10000, 100 obstacles, no tolerance.
    let obstacles: Vec<_> = (0..100)
        .map(|j| json!({"center": [j % 10, j / 10], "weight": 10}))
        .collect();
    let doc = json!({"horizon": 10000, "dt": 0.005, "obstacles": obstacles,
                     "solver": {"tolerance": 0, "max_iterations": 10000},
                     "output": {"gains": false, "trace": false}});
    std::fs::write(&problem, doc.to_string()).unwrap();
    for (signal, code) in [("-INT", 130), ("-TERM", 143)] {
        let _ = std::fs::remove_file(&out);
        let mut child = Command::new(env!("CARGO_BIN_EXE_ilqr-service"))
            .arg("solve")
            .arg(&problem)
            .arg("-o")
            .arg(&out)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // Parsing and the first rollout take a few ms; the handler is in
        // place long before this.
        std::thread::sleep(Duration::from_millis(800));
        let sent = Instant::now();
        let kill = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(kill.success());
        let status = loop {
            if let Some(status) = child.try_wait().unwrap() {
                break status;
            }
            if sent.elapsed() > Duration::from_secs(20) {
                let _ = child.kill();
                panic!("still running 20 s after {signal}");
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let output = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(status.code(), Some(code), "{signal}: {stderr}");
        assert!(
            stderr.contains("interrupted: stopping the solve"),
            "{stderr}"
        );
        let summary = String::from_utf8(output.stdout).unwrap();
        assert!(
            summary.contains("\nstatus           cancelled"),
            "{summary}"
        );
        let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
        assert_eq!(r["status"], "cancelled");
        assert_eq!(r["states"].as_array().unwrap().len(), 10001);
        assert!(r["cost"].as_f64().unwrap() <= r["initial_cost"].as_f64().unwrap());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `convexified_after_iteration` is absent for the seed, and says when a
/// solve fell back to the convex model of the cost: a 200 s flight
/// (N = 4000, dt = 0.05) from a guess a hair above hover, where the exact
/// Hessian can do no more after 2 iterations.
#[test]
fn the_result_says_when_the_solve_fell_back_to_the_convex_model() {
    let cancel = AtomicBool::new(false);
    let seed = solve(&spec(json!({})), None, &cancel).unwrap();
    assert_eq!(seed.convexified_after_iteration, None);
    let wire: serde_json::Value = serde_json::from_slice(&seed.to_json().unwrap()).unwrap();
    assert!(wire.get("convexified_after_iteration").is_none(), "{wire}");
    assert!(wire.get("convex_model_at_end").is_none(), "{wire}");

    let long = spec(json!({
        "horizon": 4000,
        "initial_controls": vec![[4.9051, 4.9051]; 4000],
        "output": {"gains": false},
    }));
    let r = solve(&long, None, &cancel).unwrap();
    assert_eq!(r.status.as_str(), "converged", "{:?}", r.status);
    assert_eq!(r.convexified_after_iteration, Some(2));
    // The exact Hessian, back to check the convex model's minimum, confirms
    // it (one more step, 1e-9 lower) and gives the gains.
    assert_eq!(r.convex_model_at_end, Some(false));
    // The trace says which model each iteration used: exact for the first
    // two, convex from the third, exact again for the check.
    let convex: Vec<bool> = r
        .trace
        .as_ref()
        .unwrap()
        .iter()
        .map(|t| t.convex_model)
        .collect();
    let back = convex.iter().rposition(|&c| c).map_or(0, |i| i + 1);
    assert!(
        convex[..2] == [false, false]
            && back < convex.len()
            && convex[2..back].iter().all(|&c| c)
            && !convex[back..].contains(&true),
        "convex model in rows {convex:?}"
    );
    assert!(
        r.cost < 0.05 * r.initial_cost,
        "{} from {}",
        r.cost,
        r.initial_cost
    );
    assert!(r.goal_distance < 0.01, "{}", r.goal_distance);
    let text = ilqr_service::cli::summary(&long, &r);
    assert!(
        text.contains("\nconvexified      after iteration 2 "),
        "{text}"
    );

    // A fallback whose convex model completed no pass either has no gains
    // to attribute to a model (the summary does not say "the exact Hessian
    // took over again"). Its cost, 1.8e24, is written in exponent form.
    let stuck = spec(json!({
        "model": {"mass": 1e-6, "inertia": 1e-6, "arm_length": 1e6, "gravity": 1e4},
        "dt": 10,
        "initial_state": [1e6, -1e6, 1e6, 1e6, -1e6, 1e6],
        "obstacles": [{"center": [1e6, -1e6], "weight": 1e12}],
    }));
    let r = solve(&stuck, None, &cancel).unwrap();
    assert!(r.gains.is_none() && r.convexified_after_iteration.is_some());
    let text = ilqr_service::cli::summary(&stuck, &r);
    assert!(
        text.contains("; no backward pass completed with either model, so no gains\n"),
        "{text}"
    );
    let cost = text.lines().find(|l| l.starts_with("cost")).unwrap();
    assert_eq!(
        cost.split_whitespace().nth(1),
        Some(&*format!("{:.6e}", r.cost))
    );
}

/// The summary shows small and large numbers in exponent form rather
/// than as 0.000005 or 38 digits, and ordinary ones with six decimals.
#[test]
fn the_summary_writes_every_cost_with_its_significant_digits() {
    let cancel = AtomicBool::new(false);
    let tiny = spec(json!({
        "weights": {"state": vec![1e-9; 6], "control": [1e-10, 1e-10], "terminal": vec![5e-5; 6]},
        "obstacles": [{"center": [4.5, 4.5], "weight": 1e-6}],
    }));
    let r = solve(&tiny, None, &cancel).unwrap();
    let text = ilqr_service::cli::summary(&tiny, &r);
    let cost = text.lines().find(|l| l.starts_with("cost")).unwrap();
    assert!(r.cost < 1e-3);
    assert_eq!(
        cost.split_whitespace()
            .nth(1)
            .unwrap()
            .parse::<f64>()
            .unwrap(),
        format!("{:.6e}", r.cost).parse::<f64>().unwrap(),
        "{cost}"
    );
    let seed = solve(&spec(json!({})), None, &cancel).unwrap();
    let text = ilqr_service::cli::summary(&spec(json!({})), &seed);
    assert!(text.contains("\ncost             5418.303"), "{text}");
}

/// Feedback gains (N × 2 × 6, row-major) and the states they are about.
type Policy<'a> = (&'a [Rows], &'a Rows);

/// Rows of two controls as pairs.
fn pairs(rows: &Rows) -> Vec<[f64; 2]> {
    rows.iter().map(|u| [u[0], u[1]]).collect()
}

/// Rolls `controls` out from `x0` under the seed's model and `dt`, with
/// feedback `u = ū_k + K_k·(x − x̄_k)` when `policy` gives `(K, x̄)`
/// (`feedback` read row-major: row i is rotor i's gains over the 6 states).
fn fly(
    x0: [f64; 6],
    dt: f64,
    controls: &[[f64; 2]],
    policy: Option<Policy<'_>>,
) -> (Vec<[f64; 2]>, [f64; 6]) {
    let controls: Vec<[f64; 2]> = controls.to_vec();
    use ilqr::{DiscreteDynamics, Euler, Quadrotor2D};
    use nalgebra::{SVector, Vector2};
    let dynamics = Euler {
        model: Quadrotor2D {
            mass: 1.0,
            inertia: 1.0,
            arm_length: 1.0,
            gravity: 9.81,
        },
        dt,
    };
    let mut x = SVector::<f64, 6>::from(x0);
    let mut flown = Vec::with_capacity(controls.len());
    for (k, u_bar) in controls.iter().enumerate() {
        let mut u = *u_bar;
        if let Some((feedback, states)) = policy {
            for (i, ui) in u.iter_mut().enumerate() {
                *ui += (0..6)
                    .map(|j| feedback[k][i][j] * (x[j] - states[k][j]))
                    .sum::<f64>();
            }
        }
        x = dynamics.step(&x, &Vector2::from(u));
        flown.push(u);
    }
    (flown, x.into())
}

/// The wire's `gains` are the solver's policy, in the documented layout:
/// from a start 0.3 m off, feedback with the wire `feedback` ends far
/// nearer the goal than the open-loop controls (a transposed or rotor-
/// swapped `feedback` does not); and a small step along `feedforward`,
/// with that feedback, lowers the cost of an unfinished solve (a sign
/// error raises it).
#[test]
fn the_wire_gains_are_the_policy() {
    let cancel = AtomicBool::new(false);
    let r = solve(&spec(json!({})), None, &cancel).unwrap();
    let gains = r.gains.as_ref().unwrap();
    let goal = [4.0, 9.0];
    let miss = |x: [f64; 6]| (x[0] - goal[0]).hypot(x[1] - goal[1]);
    let start = [5.3, -0.2, 0.0, 0.0, 0.0, 0.0];
    let controls = pairs(&r.controls);
    let (_, open) = fly(start, 0.05, &controls, None);
    let (_, closed) = fly(start, 0.05, &controls, Some((&gains.feedback, &r.states)));
    assert!(
        miss(closed) < 0.5 * miss(open),
        "closed loop misses by {}, open loop by {}",
        miss(closed),
        miss(open)
    );

    let one = solve(
        &spec(json!({"solver": {"max_iterations": 1}})),
        None,
        &cancel,
    )
    .unwrap();
    let gains = one.gains.as_ref().unwrap();
    assert!(!gains.about_previous_iterate);
    let nudged: Vec<[f64; 2]> = one
        .controls
        .iter()
        .zip(gains.feedforward.iter())
        .map(|(u, d)| [u[0] + 1e-3 * d[0], u[1] + 1e-3 * d[1]])
        .collect();
    let (flown, _) = fly(
        [5.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        0.05,
        &nudged,
        Some((&gains.feedback, &one.states)),
    );
    let scored = solve(
        &spec(json!({"initial_controls": flown, "solver": {"max_iterations": 0}})),
        None,
        &cancel,
    )
    .unwrap();
    assert!(
        scored.initial_cost < one.cost,
        "a step along feedforward: {} from {}",
        scored.initial_cost,
        one.cost
    );
}

/// Each wire trace row says what that iteration did: numbered from 1, its
/// cost the previous one less `actual_reduction`, a step size from the
/// line search's grid (0 when none was taken), and a taken step's gain
/// positive and at least the acceptance ratio (1e-4) of the model's.
#[test]
fn the_wire_trace_rows_add_up() {
    let cancel = AtomicBool::new(false);
    for doc in [
        json!({}),
        json!({"obstacles": [{"center": [4.5, 4.5], "weight": 1000}, {"center": [3, 6], "weight": 300}]}),
    ] {
        let r = solve(&spec(doc), None, &cancel).unwrap();
        let trace = r.trace.as_ref().unwrap();
        assert_eq!(trace.len(), r.iterations);
        let grid: Vec<f64> = (0..11).map(|i| 10f64.powf(-0.3 * f64::from(i))).collect();
        let mut previous = r.initial_cost;
        let mut taken = 0;
        for (i, row) in trace.iter().enumerate() {
            assert_eq!(row.iteration, i + 1);
            let expected_cost = previous - row.actual_reduction;
            assert!(
                (row.cost - expected_cost).abs() <= 1e-9 * previous,
                "row {i}: {row:?} after {previous}"
            );
            if row.step_size == 0.0 {
                assert_eq!(row.actual_reduction, 0.0, "row {i}: {row:?}");
            } else {
                taken += 1;
                assert!(grid.contains(&row.step_size), "row {i}: {row:?}");
                assert!(row.actual_reduction > 0.0, "row {i}: {row:?}");
                assert!(
                    row.actual_reduction >= 1e-4 * row.expected_reduction,
                    "row {i}: {row:?}"
                );
            }
            assert!(row.regularization >= 0.0);
            previous = row.cost;
        }
        assert!(taken > 5, "{taken} steps taken");
        assert_eq!(previous, r.cost);
    }
}

/// Every weight and obstacle of the request reaches the cost the solver
/// minimises: with unequal diagonals and obstacles off the diagonal, the
/// cost recomputed from the answer's states and controls (eqs. 13–15) is
/// the answer's `cost` (a weight or an axis wired wrong is not).
#[test]
fn the_reported_cost_is_the_requested_cost_of_the_returned_trajectory() {
    let q = [1.0, 2.0, 0.5, 0.3, 0.7, 0.2];
    let r_w = [0.1, 0.4];
    let qf = [5e4, 3e4, 1e3, 2e3, 4e3, 6e3];
    let goal = [4.0, 9.0, 0.0, 0.0, 0.0, 0.0];
    let obstacles = [([3.0, 6.0], 300.0), ([6.0, 2.0], 800.0)];
    let doc = json!({
        "weights": {"state": q, "control": r_w, "terminal": qf},
        "obstacles": obstacles
            .iter()
            .map(|(c, w)| json!({"center": c, "weight": w}))
            .collect::<Vec<_>>(),
        "solver": {"max_iterations": 5},
    });
    let r = solve(&spec(doc), None, &AtomicBool::new(false)).unwrap();
    let tracking =
        |x: &[f64], w: &[f64; 6]| -> f64 { (0..6).map(|i| w[i] * (x[i] - goal[i]).powi(2)).sum() };
    let mut cost = 0.0;
    for (x, u) in r.states.iter().zip(r.controls.iter()) {
        cost += tracking(x, &q) + r_w[0] * u[0] * u[0] + r_w[1] * u[1] * u[1];
        for (c, w) in &obstacles {
            cost += w * (-(x[0] - c[0]).hypot(x[1] - c[1])).exp();
        }
    }
    cost += tracking(&r.states[r.states.len() - 1], &qf);
    assert!(
        (cost - r.cost).abs() <= 1e-9 * r.cost,
        "recomputed {cost}, reported {}",
        r.cost
    );
}

/// `closest_approach` is the distance to the segment between two states,
/// not to its extension: flying from x = 0 to x = 1 in one step, an
/// obstacle at x = 3 is 2 m away at the segment's end (1 m along the
/// extension).
#[test]
fn closest_approach_stops_at_the_segment_end() {
    let doc = json!({
        "initial_state": [0, 0, 0, 1, 0, 0],
        "dt": 1,
        "horizon": 1,
        "model": {"gravity": 0},
        "initial_controls": [[0, 0]],
        "obstacles": [{"center": [3, 0], "weight": 0}],
        "solver": {"max_iterations": 0},
    });
    let r = solve(&spec(doc), None, &AtomicBool::new(false)).unwrap();
    assert_eq!(r.states[1][0], 1.0);
    assert_eq!(r.closest_approach, vec![2.0]);
}

/// DDP's dynamics curvature can make `V_xx` indefinite where no μ on
/// `Q_uu` helps, even without obstacles, where the cost has nothing to
/// convexify: without a fallback this problem would end `no_progress` at
/// iteration 0 with no gains, where iLQR converges in 6. The convex model
/// also drops the dynamics' curvature, so DDP falls back to iLQR's model
/// and converges with it.
#[test]
fn ddp_without_obstacles_falls_back_to_the_first_order_model() {
    let cancel = AtomicBool::new(false);
    let problem = |method: &str| {
        spec(json!({
            "dt": 1.7573381559589116, "horizon": 200,
            "initial_state": [5.846424938148553, 0.8722693513604585, 0.3074465662808368, 0, 0, 0],
            "goal_state": [2.424403214069132, 2.9500778890144006, 0, 0, 0, 0],
            "obstacles": [],
            "weights": {"state": vec![5.13; 6], "control": [0.0074, 0.0074], "terminal": vec![2573; 6]},
            "solver": {"method": method},
        }))
    };
    let ilqr = solve(&problem("ilqr"), None, &cancel).unwrap();
    let ddp = solve(&problem("ddp"), None, &cancel).unwrap();
    assert_eq!(ilqr.status.as_str(), "converged");
    assert_eq!(
        ddp.status.as_str(),
        "converged",
        "{} iterations",
        ddp.iterations
    );
    assert!(ddp.convexified_after_iteration.is_some());
    assert!(
        (ddp.cost - ilqr.cost).abs() <= 1e-6 * ilqr.cost,
        "{} {}",
        ddp.cost,
        ilqr.cost
    );
    assert!(ddp.gains.is_some());
}
