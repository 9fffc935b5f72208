//! The command line: `serve` (the default: its flags work without the
//! subcommand too), `solve`, `openapi` and `healthcheck`. Each subcommand
//! is a few lines over the library.

use std::io::{Read, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicUsize, Ordering};

use clap::{Parser, Subcommand};

use crate::problem::{Invalid, Limits, ParseError, ProblemSpec, parse};
use crate::server::{self, Config};
use crate::solve::{Budget, Helper, Helpers, SolveResult, solve_shared};

/// Trajectory optimisation with iLQR, served over HTTP and gRPC.
///
/// With no subcommand the binary serves, taking the flags of `serve`
/// (`ilqr-service --bind 127.0.0.1:9000`); they cannot be combined with
/// a subcommand.
#[derive(Debug, Parser)]
#[command(
    name = "ilqr-service",
    version,
    about,
    long_about,
    args_conflicts_with_subcommands = true
)]
pub struct Cli {
    /// The settings of serving without a subcommand. Before a subcommand
    /// they are not read at all (see [`parse_or_exit`]).
    #[command(flatten)]
    serve: Config,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Serve the HTTP API and the gRPC one (also what the binary does with
    /// no subcommand, with the same flags).
    Serve(Config),
    /// Solve one problem file and print a summary.
    ///
    /// Ctrl-C stops the solve and still writes its best trajectory (status
    /// `cancelled`, exit code 130, or 143 for SIGTERM); a second Ctrl-C
    /// before the solve has stopped quits at once, writing nothing. Exit
    /// codes: 0 solved (whatever the status), 1 a runtime failure (an
    /// unreadable problem file, an unwritable output), 2 an invalid
    /// problem, 130 or 143 interrupted. A reader that closes standard
    /// output early (`-o - | head`) ends the command quietly (exit code 0).
    Solve {
        /// Problem JSON; `-` reads standard input. Omitted: the seed problem.
        problem: Option<PathBuf>,
        /// Write the full result JSON here (`-` for standard output).
        #[arg(long, short)]
        output: Option<PathBuf>,
    },
    /// Print the OpenAPI document.
    Openapi,
    /// Exit 0 if the service on this machine answers `GET /healthz` with 200
    /// (for container health checks, which have no curl).
    Healthcheck {
        /// Address of the service, HOST:PORT (`127.0.0.1:8080`,
        /// `localhost:8080`; every address a name resolves to is tried).
        /// Default: `ILQR_BIND`, so it follows the server's setting; an
        /// all-interfaces bind is checked on loopback at its port
        /// (`0.0.0.0` on `127.0.0.1`, `[::]` on `[::1]` then `127.0.0.1`),
        /// and an unset (or empty) one at `127.0.0.1:8080`. An `ILQR_BIND`
        /// that is not IP:PORT is an error (exit code 1), since the server
        /// would refuse it too: which address to check is then unknown.
        #[arg(long, env = "ILQR_HEALTHCHECK_ADDR")]
        addr: Option<String>,
    },
}

/// Run the command line; the exit code is 0 on success, 1 on a runtime
/// failure, 2 on invalid input and 130 or 143 for a `solve` stopped by
/// SIGINT or SIGTERM.
pub fn main() -> ExitCode {
    let cli = parse_or_exit(std::env::args_os().collect());
    match cli.command {
        // No subcommand means `serve`, with the flags given at the top level.
        None => serve(cli.serve),
        Some(Command::Serve(config)) => serve(config),
        Some(Command::Solve { problem, output }) => solve_file(problem, output),
        Some(Command::Openapi) => {
            println!("{}", server::openapi_json());
            ExitCode::SUCCESS
        }
        Some(Command::Healthcheck { addr }) => {
            let checked = match addr {
                Some(addr) => server::healthcheck(&addr),
                None => match local_addrs() {
                    Ok(addrs) => server::healthcheck_any(&addrs),
                    Err(e) => {
                        eprintln!("error: {e}");
                        // 1, not the CLI's 2 for bad settings: to a
                        // container runtime any other code than 1 is not
                        // "unhealthy" (Docker reserves 2).
                        return ExitCode::FAILURE;
                    }
                },
            };
            match checked {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("unhealthy: {e}");
                    ExitCode::FAILURE
                }
            }
        }
    }
}

/// Parse the command line, or exit with clap's message (the source of a
/// bad value named, see [`name_env_source`]).
///
/// Two adjustments to clap: an `ILQR_*` variable that is set but empty
/// counts as unset (see [`server::unset_empty_env`]); and the top-level
/// serve settings do not read their variables when a subcommand is run,
/// since clap reads a command's variables after its subcommand's, so a
/// bad `ILQR_WORKERS` would otherwise stop `solve` and `healthcheck`,
/// which have no use for it.
fn parse_or_exit(args: Vec<std::ffi::OsString>) -> Cli {
    use clap::{CommandFactory, FromArgMatches};
    let mut cmd = server::unset_empty_env(Cli::command());
    if subcommand_in(&args, &cmd).is_some() {
        cmd = cmd.mut_args(|arg| arg.env(None));
    }
    cmd.try_get_matches_from_mut(&args)
        .and_then(|matches| Cli::from_arg_matches(&matches))
        .unwrap_or_else(|e| name_env_source(e.format(&mut cmd), args).exit())
}

/// The subcommand `args` run, if any: with the top-level flags in conflict
/// with subcommands, it can only be the first argument.
fn subcommand_in<'a>(args: &'a [std::ffi::OsString], cmd: &clap::Command) -> Option<&'a str> {
    let first = args.get(1)?.to_str()?;
    (first == "help" || cmd.find_subcommand(first).is_some()).then_some(first)
}

/// A flag's value that came from its environment variable is reported
/// under the variable's name: clap names the flag (`invalid value 'abc'
/// for '--workers <WORKERS>'`) even when the command line has no such
/// flag, which sends a container user looking in the wrong place.
fn name_env_source(
    mut err: clap::Error,
    args: impl IntoIterator<Item = std::ffi::OsString>,
) -> clap::Error {
    use clap::CommandFactory;
    use clap::error::{ContextKind, ContextValue, ErrorKind};
    let os_args: Vec<std::ffi::OsString> = args.into_iter().collect();
    // clap says only "invalid UTF-8 was detected in one or more arguments";
    // when the command line is clean, the culprit is a variable, a place a
    // user would not look.
    let args: Vec<&str> = os_args.iter().filter_map(|a| a.to_str()).collect();
    if err.kind() == ErrorKind::InvalidUtf8 && args.len() == os_args.len() {
        // The variables clap read: those of the subcommand being run (none
        // means the top level's, which are `serve`'s) whose flag is not on
        // the command line.
        let cmd = Cli::command();
        let runs = match subcommand_in(&os_args, &cmd) {
            Some(sub) => cmd.find_subcommand(sub),
            None => Some(&cmd),
        };
        let bad: Vec<&str> = runs
            .into_iter()
            .flat_map(clap::Command::get_arguments)
            .filter(|a| {
                a.get_long()
                    .is_none_or(|long| !on_command_line(&args, long))
            })
            .filter_map(|a| a.get_env()?.to_str())
            .filter(|name| std::env::var_os(name).is_some_and(|v| v.to_str().is_none()))
            .collect();
        let message = match bad.as_slice() {
            [] => None,
            [one] => Some(format!("the value of {one} is not valid UTF-8")),
            many => Some(format!(
                "the values of {} are not valid UTF-8",
                many.join(", ")
            )),
        };
        if let Some(message) = message {
            return clap::Error::raw(ErrorKind::InvalidUtf8, format!("{message}\n"));
        }
    }
    if !matches!(
        err.kind(),
        ErrorKind::ValueValidation | ErrorKind::InvalidValue
    ) {
        return err;
    }
    let Some(ContextValue::String(label)) = err.get(ContextKind::InvalidArg) else {
        return err;
    };
    // "--workers <WORKERS>" -> "workers"
    let Some(long) = label
        .strip_prefix("--")
        .and_then(|l| l.split(' ').next())
        .map(str::to_owned)
    else {
        return err;
    };
    if on_command_line(&args, &long) {
        return err;
    }
    let cmd = Cli::command();
    let env = std::iter::once(&cmd)
        .chain(cmd.get_subcommands())
        .flat_map(clap::Command::get_arguments)
        .find(|a| a.get_long() == Some(long.as_str()))
        .and_then(|a| a.get_env())
        .and_then(|e| e.to_str())
        .map(str::to_owned);
    if let Some(env) = env {
        err.insert(ContextKind::InvalidArg, ContextValue::String(env));
    }
    err
}

/// Whether `--LONG` is given in `args` (`--LONG VALUE` or `--LONG=VALUE`).
fn on_command_line(args: &[&str], long: &str) -> bool {
    let flag = format!("--{long}");
    args.iter().any(|a| {
        a.strip_prefix(flag.as_str())
            .is_some_and(|rest| rest.is_empty() || rest.starts_with('='))
    })
}

/// Where a service started with the same environment listens: `ILQR_BIND`
/// itself when it names one address (`[::1]:9000`, `10.0.0.5:8080`), or
/// loopback at its port when it binds every interface (`0.0.0.0:8080` →
/// `127.0.0.1:8080`; `[::]:8080` → `[::1]:8080`, then `127.0.0.1:8080`,
/// since `[::]` takes IPv4 too and a container may have no IPv6
/// loopback); `127.0.0.1:8080` when unset or empty, as for the server.
///
/// An `ILQR_BIND` that is not IP:PORT is an error naming it: checking
/// 127.0.0.1:8080 instead would report on some other service (or on
/// nothing) while saying nothing of the typo.
fn local_addrs() -> Result<Vec<std::net::SocketAddr>, String> {
    use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
    let addr = match std::env::var_os("ILQR_BIND") {
        Some(bind) if !bind.is_empty() => bind
            .to_str()
            .and_then(|b| b.parse::<SocketAddr>().ok())
            .ok_or_else(|| {
                // Bounded: a variable can be long, and this is one line.
                let shown: String = bind.to_string_lossy().chars().take(100).collect();
                format!(
                    "ILQR_BIND is {shown:?}, which is not IP:PORT (e.g. 0.0.0.0:8080), so the \
                     address to check is unknown; fix it, or give the address with --addr or \
                     ILQR_HEALTHCHECK_ADDR"
                )
            })?,
        _ => SocketAddr::from((Ipv4Addr::LOCALHOST, 8080)),
    };
    let v4 = SocketAddr::from((Ipv4Addr::LOCALHOST, addr.port()));
    Ok(match addr.ip() {
        IpAddr::V4(ip) if ip.is_unspecified() => vec![v4],
        IpAddr::V6(ip) if ip.is_unspecified() => {
            vec![SocketAddr::from((Ipv6Addr::LOCALHOST, addr.port())), v4]
        }
        _ => vec![addr],
    })
}

fn serve(config: Config) -> ExitCode {
    if let Err(e) = config.check() {
        eprintln!("error: {e}");
        return ExitCode::from(2);
    }
    match server::serve_forever(config) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn solve_file(problem: Option<PathBuf>, output: Option<PathBuf>) -> ExitCode {
    let spec = match read_problem(problem.as_ref()) {
        Ok(spec) => spec,
        // Not a problem at all: exit 1, so that a script can tell a wrong
        // path from a wrong problem.
        Err(ReadError::Io(line)) => {
            eprintln!("error: {line}");
            return ExitCode::FAILURE;
        }
        Err(ReadError::Invalid(lines)) => {
            for l in lines {
                eprintln!("error: {l}");
            }
            return ExitCode::from(2);
        }
    };
    // Check the output before solving, so that an unwritable path fails at
    // once rather than after a long solve.
    let out_path = output.as_ref().filter(|p| p.as_os_str() != "-");
    let target = match out_path {
        None => None,
        Some(path) => match OutputTarget::open(path) {
            Ok(t) => Some(t),
            Err(e) => {
                eprintln!("error: cannot write {}: {e}", path.display());
                return ExitCode::FAILURE;
            }
        },
    };
    let signals = Signals::watch();
    // A search's starts also run on threads of their own, one per core
    // beside this one.
    let spare = AtomicUsize::new(std::thread::available_parallelism().map_or(1, |n| n.get()) - 1);
    let lend = |job: Helper| {
        let free = spare.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| n.checked_sub(1));
        if free.is_err() {
            return Err(job);
        }
        match std::thread::Builder::new()
            .name("search".into())
            .spawn(move || job(&|| false))
        {
            Ok(_) => Ok(()),
            // No thread: the job is gone with the error, and its starts
            // run here (the search never handed it a start).
            Err(_) => Ok(()),
        }
    };
    let helpers = Helpers {
        spec: Arc::new(spec.clone()),
        cancel: Arc::clone(&signals.cancel),
        lend: &lend,
    };
    let budget = Budget {
        time_limit: spec.time_limit(None),
        ..Budget::default()
    };
    let solved = solve_shared(helpers, budget, &mut |_| {});
    signals.finishing.store(true, Ordering::SeqCst);
    let result = match solved {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: {}: {}", pointer_label(&e.0.pointer), e.0.detail);
            return ExitCode::from(2);
        }
    };
    // Only a signal sets the flag, so `cancelled` means interrupted.
    let interrupted = result.status.as_str() == "cancelled";
    // With `-o -` the JSON owns standard output (to pipe into jq), so the
    // summary goes to standard error.
    let json_to_stdout = output.as_ref().is_some_and(|p| p.as_os_str() == "-");
    let text = summary(&spec, &result);
    if json_to_stdout {
        eprint!("{text}");
    } else {
        // Not `print!`, which panics when the reader has gone (`| head
        // -1`); then the output file, if any, is still written.
        let printed = write!(std::io::stdout().lock(), "{text}");
        if let Err(e) = printed.and_then(|()| std::io::stdout().flush())
            && !reader_left(&e)
        {
            eprintln!("error: cannot write the summary to standard output: {e}");
            return ExitCode::FAILURE;
        }
    }
    if let Some(path) = output.as_ref() {
        let json = match serde_json::to_string_pretty(&result) {
            Ok(j) => j,
            Err(e) => {
                eprintln!("error: cannot serialise the result: {e}");
                return ExitCode::FAILURE;
            }
        };
        let written = match target {
            None => writeln!(std::io::stdout(), "{json}"),
            Some(target) => target.write_line(&json),
        };
        match written {
            Ok(()) => {}
            // A reader that took what it wanted and left (`-o - | head`)
            // is how a pipeline ends, not a failure: end quietly, as a
            // Unix filter does.
            Err(e) if reader_left(&e) => {}
            Err(e) => {
                eprintln!("error: cannot write {}: {e}", path.display());
                return ExitCode::FAILURE;
            }
        }
    }
    if interrupted {
        // 128 + the signal's number, as a shell reports a command the
        // signal ended, so that a script can tell; the result was still
        // written.
        return ExitCode::from(signals.code.load(Ordering::SeqCst));
    }
    ExitCode::SUCCESS
}

/// Whether a write failed because the reading end of a pipe (standard
/// output into `head`, a named pipe) was closed. Rust ignores SIGPIPE, so
/// this comes back as an error instead of ending the process.
fn reader_left(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::BrokenPipe
}

/// What SIGINT and SIGTERM do to `solve`. The first one during the solve
/// sets `cancel`: the solve stops within a few milliseconds (it polls every
/// 128 knots) with status `cancelled` and the best trajectory so far, which
/// is then printed and written like any result. Another one before the
/// solve has returned quits at once, writing nothing; once it has returned
/// (`finishing`), signals are ignored, so that the result file is written
/// whole.
///
/// The handlers are installed from a thread of their own, with a
/// single-threaded runtime for tokio's signal streams; until they are (a
/// millisecond or so after the solve starts), a signal has its default
/// effect.
struct Signals {
    cancel: Arc<AtomicBool>,
    finishing: Arc<AtomicBool>,
    /// The exit code for the signal received: 130 (SIGINT), 143 (SIGTERM).
    code: Arc<AtomicU8>,
}

impl Signals {
    fn watch() -> Self {
        let signals = Self {
            cancel: Arc::new(AtomicBool::new(false)),
            finishing: Arc::new(AtomicBool::new(false)),
            code: Arc::new(AtomicU8::new(130)),
        };
        let (cancel, finishing, code) = (
            Arc::clone(&signals.cancel),
            Arc::clone(&signals.finishing),
            Arc::clone(&signals.code),
        );
        let watch = move || {
            let Ok(rt) = tokio::runtime::Builder::new_current_thread()
                .enable_io()
                .build()
            else {
                return; // No handler then: a signal ends the process as usual.
            };
            rt.block_on(async {
                let mut first = true;
                // One listener for all the signals, so that none is missed
                // between two of them.
                let mut stop = server::StopSignals::new();
                loop {
                    let received = stop.next().await;
                    if finishing.load(Ordering::SeqCst) {
                        eprintln!("finishing: writing the result");
                    } else if first {
                        code.store(received, Ordering::SeqCst);
                        cancel.store(true, Ordering::SeqCst);
                        eprintln!(
                            "interrupted: stopping the solve to write the best trajectory \
                             so far (interrupt again to quit at once)"
                        );
                    } else {
                        std::process::exit(i32::from(received));
                    }
                    first = false;
                }
            });
        };
        // Without the thread the solve still runs; it just cannot be
        // stopped gently.
        let _ = std::thread::Builder::new()
            .name("signals".into())
            .spawn(watch);
        signals
    }
}

/// Where `solve -o PATH` writes the result, settled before the solve.
enum OutputTarget {
    /// A regular file, existing or not: checked by opening it for writing
    /// without truncating (and removing it again if that created it, through
    /// any symlink), so nothing is left behind if the solve fails or the
    /// process is killed and an existing file keeps its content until the
    /// result is written, by creating it anew.
    File(PathBuf),
    /// This process's own standard output under another name
    /// (`-o /dev/stdout`, whether it is a terminal, a pipe or a file it was
    /// redirected to): written through it, after the summary, without
    /// truncating what was written there before.
    Stdout,
    /// Anything else that exists (`/dev/null`, a named pipe, `>(jq .)`):
    /// opened once, now, and kept open, since a pipe's reader sees the end
    /// of its input when the writer closes it, and nothing there can be
    /// truncated.
    Stream(std::fs::File),
}

impl OutputTarget {
    fn open(path: &std::path::Path) -> std::io::Result<Self> {
        use std::os::unix::fs::MetadataExt;
        let existing = match std::fs::metadata(path) {
            Ok(m) => Some(m),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(e) => return Err(e),
        };
        let stdout_id = stdout_metadata().map(|m| (m.dev(), m.ino()));
        match existing {
            Some(m) if Some((m.dev(), m.ino())) == stdout_id => Ok(Self::Stdout),
            Some(m) if !m.is_file() => std::fs::OpenOptions::new()
                .write(true)
                .open(path)
                .map(Self::Stream),
            _ => {
                std::fs::OpenOptions::new()
                    .write(true)
                    .create(true)
                    .truncate(false)
                    .open(path)?;
                if existing.is_none() {
                    // Through a dangling symlink the file made is the
                    // link's target: remove that, not the link.
                    let made = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_owned());
                    let _ = std::fs::remove_file(made);
                }
                Ok(Self::File(path.to_owned()))
            }
        }
    }

    /// Write `text` and a newline (without copying `text`, which can be
    /// megabytes).
    fn write_line(self, text: &str) -> std::io::Result<()> {
        fn line(mut w: impl Write, text: &str) -> std::io::Result<()> {
            w.write_all(text.as_bytes())?;
            w.write_all(b"\n")?;
            w.flush()
        }
        match self {
            Self::File(path) => line(std::io::BufWriter::new(std::fs::File::create(path)?), text),
            Self::Stdout => line(std::io::stdout().lock(), text),
            Self::Stream(file) => line(file, text),
        }
    }
}

/// The file behind standard output, if it can be inspected.
fn stdout_metadata() -> Option<std::fs::Metadata> {
    use std::os::fd::AsFd;
    let fd = std::io::stdout().as_fd().try_clone_to_owned().ok()?;
    std::fs::File::from(fd).metadata().ok()
}

/// Why `solve` has no problem to solve.
enum ReadError {
    /// The file or standard input could not be read (exit code 1).
    Io(String),
    /// It was read, and is not a valid problem: one line per invalid value
    /// (exit code 2).
    Invalid(Vec<String>),
}

fn read_problem(path: Option<&PathBuf>) -> Result<ProblemSpec, ReadError> {
    let bytes = match path {
        None => return Ok(ProblemSpec::default()),
        Some(p) if p.as_os_str() == "-" => {
            let mut buf = Vec::new();
            std::io::stdin()
                .read_to_end(&mut buf)
                .map_err(|e| ReadError::Io(format!("cannot read standard input: {e}")))?;
            buf
        }
        Some(p) => std::fs::read(p)
            .map_err(|e| ReadError::Io(format!("cannot read {}: {e}", p.display())))?,
    };
    let limits = Limits::default();
    let spec = parse(&bytes).map_err(|e| {
        ReadError::Invalid(match e {
            // Named like a read error: the line and column are no help
            // without the file (a script may solve many).
            ParseError::Syntax(msg) => vec![format!(
                "{} is not valid JSON: {msg}",
                path.map_or("the problem".into(), |p| if p.as_os_str() == "-" {
                    "standard input".into()
                } else {
                    p.display().to_string()
                })
            )],
            ParseError::Shape(shapes) => error_lines(&shapes.with_range_errors(&limits)),
        })
    })?;
    spec.validate(&limits)
        .map_err(|invalid| ReadError::Invalid(error_lines(&invalid)))?;
    Ok(spec)
}

/// One line per invalid value, and one for the count of those not listed.
fn error_lines(invalid: &Invalid) -> Vec<String> {
    let mut lines: Vec<String> = invalid
        .errors
        .iter()
        .map(|f| format!("{}: {}", pointer_label(&f.pointer), f.detail))
        .collect();
    if invalid.unlisted > 0 {
        let values = if invalid.unlisted == 1 {
            "value"
        } else {
            "values"
        };
        let listed = match invalid.errors.len() {
            1 => "the first is".to_owned(),
            n => format!("the first {n} are"),
        };
        lines.push(format!(
            "{} more invalid {values} not listed (only {listed})",
            invalid.unlisted
        ));
    }
    if invalid.incomplete {
        lines.push(
            "checking stopped here: more values may be invalid; fix these and run again".into(),
        );
    }
    lines
}

fn pointer_label(pointer: &str) -> &str {
    if pointer.is_empty() {
        "(problem)"
    } else {
        pointer
    }
}

/// Six decimals where that shows the number (0.001 to 1e9, or 0), the
/// same six significant places in exponent form elsewhere: `{:.6}` alone
/// prints a cost of 5.4e-6 as 0.000005 and one of 5.2e37 as 38 digits.
fn six_places(x: f64) -> String {
    if x == 0.0 || (1e-3..1e9).contains(&x.abs()) || !x.is_finite() {
        format!("{x:.6}")
    } else {
        format!("{x:.6e}")
    }
}

/// The human summary printed by `solve`.
pub fn summary(spec: &ProblemSpec, r: &SolveResult) -> String {
    let mut s = format!(
        "model            {} ({})\nstatus           {}\niterations       {}\ncost             {} (initial {})\ngoal distance    {} m\n",
        r.model,
        r.integrator.as_str(),
        r.status.as_str(),
        r.iterations,
        six_places(r.cost),
        six_places(r.initial_cost),
        six_places(r.goal_distance),
    );
    // Up to SHOWN obstacles: with more, the nearest SHOWN (in index
    // order); the result's `closest_approach` has every one.
    const SHOWN: usize = 10;
    let mut nearest: Vec<usize> = (0..r.closest_approach.len()).collect();
    nearest.sort_by(|&a, &b| r.closest_approach[a].total_cmp(&r.closest_approach[b]));
    let mut shown: Vec<usize> = nearest.iter().copied().take(SHOWN).collect();
    shown.sort_unstable();
    for j in shown {
        let (Some(o), Some(d)) = (spec.obstacles.get(j), r.closest_approach.get(j)) else {
            continue;
        };
        // Padded like the other labels, however many digits `j` has.
        s += &format!(
            "{:<17}closest approach {d:.4} m to ({}, {})\n",
            format!("obstacle {j}"),
            o.center[0],
            o.center[1]
        );
    }
    if let Some(&next) = nearest.get(SHOWN) {
        s += &format!(
            "{:<17}{} more, none nearer than {:.4} m (closest_approach in the result lists all)\n",
            "",
            nearest.len() - SHOWN,
            r.closest_approach[next]
        );
    }
    if let Some(c) = &r.constraint_report {
        s += &format!(
            "constraints      violation {:.2e} after {} outer iterations\n",
            r.constraint_violation, c.outer_iterations
        );
        let steps = |n: usize| if n == 1 { "step" } else { "steps" };
        for (name, status) in [
            ("control bounds", &c.control),
            ("state bounds", &c.state),
            ("goal tolerance", &c.goal),
        ] {
            if let Some(t) = status {
                s += &format!(
                    "{:<17}violation {:.2e}, active at {} {}\n",
                    name,
                    t.max_violation,
                    t.active_steps,
                    steps(t.active_steps)
                );
            }
        }
        for o in &c.obstacles {
            s += &format!(
                "{:<17}violation {:.2e}, active at {} {}, smallest distance {:.4} m\n",
                format!("hard obstacle {}", o.obstacle),
                o.max_violation,
                o.active_steps,
                steps(o.active_steps),
                o.smallest_distance
            );
        }
    }
    for w in &r.warnings {
        s += &format!("warning          {}: {}\n", w.code.as_str(), w.message);
    }
    if let Some(k) = r.convexified_after_iteration {
        s += &format!(
            "convexified      after iteration {k} (no progress with the exact Hessian up to μ = 1e20); {}\n",
            // Without gains (turned off, or no pass completed with either
            // model) there is nothing to attribute to a model.
            match (
                r.convex_model_at_end == Some(true),
                r.gains.is_some(),
                spec.output.gains,
            ) {
                (true, true, _) => "the gains come from the convex model",
                (_, false, true) => "no backward pass completed with either model, so no gains",
                (true, false, false) => "it ended on the convex model",
                (false, true, _) => "the exact Hessian took over again",
                // Gains turned off: "false" is also what a solve that
                // completed no pass at all says.
                (false, false, false) => {
                    "the exact Hessian took over again, or no pass completed \
                     (ask for the gains to tell which)"
                }
            }
        );
    }
    // A search lists its starts; a single solve's one start is the result.
    if r.starts.len() > 1 {
        let width = r
            .starts
            .iter()
            .map(|st| st.label.len())
            .fold(22, usize::max);
        for (i, st) in r.starts.iter().enumerate() {
            s += &format!(
                "{:<17}{:<width$} {:<14} cost {:.6}, {} iterations{}{}{}\n",
                format!("start {i}"),
                st.label,
                st.status.as_str(),
                st.cost,
                st.iterations,
                st.guide_iterations
                    .map_or(String::new(), |g| format!(" (+{g} guiding)")),
                if st.passes.is_some() && st.passes != st.side {
                    ", slid back round the other side"
                } else {
                    ""
                },
                if st.chosen { "  <- chosen" } else { "" }
            );
        }
    }
    s += &format!("solve time       {:.3} ms\n", r.solve_time_ms);
    s
}
