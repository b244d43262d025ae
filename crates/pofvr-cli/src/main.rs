//! The `pofvr` binary: a thin layer over the `pofvr` library.

mod args;
mod cmd;
mod progress;
mod report;
mod resolve;

use clap::Parser;

fn main() {
    // Die quietly on a closed pipe (`pofvr info … | head`) like other Unix tools, instead
    // of panicking inside println!.
    #[cfg(unix)]
    // SAFETY: called first thing in main, before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = args::Cli::parse();
    if let Err(e) = run(cli) {
        eprintln!("pofvr: error: {}", message(&e));
        std::process::exit(2);
    }
}

/// The error and its causes, each cause once: many of our errors already print their
/// source (`file: reason`), and the chain would repeat it. A library error about a setting
/// is prefixed with the flag that sets it.
fn message(e: &anyhow::Error) -> String {
    let mut msg = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if msg.contains(&text) {
            continue;
        }
        if !msg.is_empty() {
            msg.push_str(": ");
        }
        if let Some(flag) = flag_of(cause) {
            msg.push_str(flag);
            msg.push_str(": ");
        }
        msg.push_str(&text);
    }
    msg
}

/// The flag of the setting a library error is about: the library names settings in words
/// ([`pofvr::error::Setting`]), never by their flags.
fn flag_of(cause: &(dyn std::error::Error + 'static)) -> Option<&'static str> {
    use pofvr::error::{OutOfRange, Setting};
    use pofvr::frame::{FrameError, JobError};
    use pofvr::pof::PofError;
    // A POF file built for another step or threshold names the setting in `what`.
    let mismatch = |e: &PofError| match e {
        PofError::Mismatch { what, .. } => [Setting::Step, Setting::EarlyTermination]
            .into_iter()
            .find(|s| s.name() == *what),
        _ => None,
    };
    let setting = if let Some(e) = cause.downcast_ref::<pofvr::Error>() {
        match e {
            pofvr::Error::OutOfRange(r) => Some(r.setting),
            pofvr::Error::Pof(p) => mismatch(p),
            _ => None,
        }
    } else if let Some(JobError::OutOfRange(r)) = cause.downcast_ref::<JobError>() {
        Some(r.setting)
    } else if let Some(FrameError::OutOfRange(r)) = cause.downcast_ref::<FrameError>() {
        Some(r.setting)
    } else if let Some(p) = cause.downcast_ref::<PofError>() {
        mismatch(p)
    } else {
        cause.downcast_ref::<OutOfRange>().map(|r| r.setting)
    }?;
    match setting {
        Setting::Step => Some("--step"),
        Setting::EarlyTermination => Some("--ert"),
        Setting::CullThreshold => Some("--cull-threshold"),
        Setting::Ranks => Some("--ranks"),
        _ => None,
    }
}

fn run(cli: args::Cli) -> anyhow::Result<()> {
    if cli.threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(cli.threads)
            .build_global()?;
    }
    let ui = progress::Ui::new(cli.quiet);
    match cli.command {
        args::Command::Info(a) => cmd::info::run(&a, &ui),
        args::Command::Render(a) => cmd::render::run(&a, &ui),
        args::Command::Demo(a) => cmd::demo::run(&a, &ui),
        args::Command::Serve(a) => cmd::serve::run(&a, &ui),
        args::Command::Experiment(a) => cmd::experiment::run(&a, &ui),
        args::Command::Bench(args::BenchCommand::Render(a)) => cmd::bench::render(&a, &ui),
        args::Command::Bench(args::BenchCommand::Cull(a)) => cmd::bench::cull(&a, &ui),
        args::Command::Bench(args::BenchCommand::Frame(a)) => cmd::bench::frame(&a, &ui),
        args::Command::Bench(args::BenchCommand::Pof(a)) => cmd::pof::bench(&a, &ui),
        args::Command::Pof(c) => cmd::pof::run(&c, &ui),
    }
}
