//! The `pofvr` binary: a thin layer over the `pofvr` library.

mod alloc;
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
        if let Some(flag) = flag_of(cause).or_else(|| flag_of_value(cause)) {
            msg.push_str(flag);
            msg.push_str(": ");
        }
        msg.push_str(&text);
        if let Some(hint) = hint_of(cause) {
            msg.push_str(hint);
        }
    }
    msg
}

/// What to do about a library error, in the CLI's terms (the library names no flags).
fn hint_of(cause: &(dyn std::error::Error + 'static)) -> Option<&'static str> {
    use pofvr::pof::PofError;
    use pofvr::volume::VolumeError;
    let pof = cause
        .downcast_ref::<PofError>()
        .or_else(|| match cause.downcast_ref() {
            Some(pofvr::Error::Pof(p)) => Some(p),
            _ => None,
        });
    if let Some(PofError::NoSets { .. }) = pof {
        return Some(" (rebuild it with `pofvr pof build --sets`)");
    }
    let volume = cause
        .downcast_ref::<VolumeError>()
        .or_else(|| match cause.downcast_ref() {
            Some(pofvr::Error::Volume(v)) => Some(v),
            _ => None,
        });
    if let Some(pofvr::Error::JitteredPofs { .. }) = cause.downcast_ref() {
        return Some(" (drop --jitter, or cull with --cull exact)");
    }
    if let Some(VolumeError::UnknownFormat { .. }) = volume {
        return Some(" (a raw file takes --dims and --dtype)");
    }
    None
}

/// The flag of a library error that is about a value set by a flag other than the
/// settings of [`flag_of`]: weights, orbit angles, owners per brick, POF levels.
fn flag_of_value(cause: &(dyn std::error::Error + 'static)) -> Option<&'static str> {
    use pofvr::distribute::DistributeError;
    use pofvr::pof::PofError;
    use pofvr::render::camera::{self, CameraError};
    use pofvr::render::TfError;
    let tf = cause
        .downcast_ref::<TfError>()
        .or_else(|| match cause.downcast_ref() {
            Some(pofvr::Error::Tf(t)) => Some(t),
            _ => None,
        });
    if let Some(TfError::Field { file, .. }) = tf {
        if file == pofvr::render::transfer_function::GIVEN_WEIGHTS {
            return Some("--weights");
        }
    }
    let camera = cause
        .downcast_ref::<CameraError>()
        .or_else(|| match cause.downcast_ref() {
            Some(pofvr::Error::Camera(c)) => Some(c),
            _ => None,
        });
    match camera {
        Some(CameraError::Angle { .. }) => return Some("--view"),
        Some(CameraError::Field { file, field, .. }) if file == camera::ORBIT => {
            return Some(if *field == "width" {
                "--size"
            } else {
                "--view"
            });
        }
        _ => {}
    }
    let dist = cause
        .downcast_ref::<DistributeError>()
        .or_else(|| match cause.downcast_ref() {
            Some(pofvr::Error::Distribute(d)) => Some(d),
            _ => None,
        });
    if let Some(DistributeError::BadReplicas { .. }) = dist {
        return Some("--replicas");
    }
    let pof = cause
        .downcast_ref::<PofError>()
        .or_else(|| match cause.downcast_ref() {
            Some(pofvr::Error::Pof(p)) => Some(p),
            _ => None,
        });
    if let Some(PofError::Setting {
        field: "core_length",
        ..
    }) = pof
    {
        return Some("--pof-level");
    }
    None
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
        args::Command::Convert(a) => cmd::convert::run(&a, &ui),
    }
}

#[cfg(test)]
mod tests {
    use super::message;
    use pofvr::distribute::DistributeError;
    use pofvr::pof::PofError;
    use pofvr::volume::VolumeError;

    #[test]
    fn library_errors_gain_the_flag_or_hint_of_the_command_line() {
        let e = anyhow::Error::new(pofvr::Error::from(DistributeError::BadReplicas {
            replicas: 4,
            ranks: 3,
        }));
        assert_eq!(
            message(&e),
            "--replicas: owners per brick: got 4, expected 1..=3 (the number of ranks)"
        );
        let e = anyhow::Error::new(PofError::NoSets {
            file: "a.pof".into(),
        });
        assert!(message(&e).ends_with("(rebuild it with `pofvr pof build --sets`)"));
        let e = anyhow::Error::new(VolumeError::UnknownFormat {
            file: "v.xyz".into(),
        });
        assert!(
            message(&e).contains("--dims and --dtype"),
            "{}",
            message(&e)
        );
        let mut tf =
            pofvr::render::families::for_phantom(pofvr::volume::phantom::Phantom::SheppLogan);
        let e = anyhow::Error::new(tf.set_weights(vec![1.0]).unwrap_err());
        assert!(message(&e).starts_with("--weights: "), "{}", message(&e));
        // Library messages themselves name no flag.
        for e in [
            pofvr::Error::from(DistributeError::BadReplicas {
                replicas: 4,
                ranks: 3,
            })
            .to_string(),
            PofError::NoSets {
                file: "a.pof".into(),
            }
            .to_string(),
            VolumeError::UnknownFormat {
                file: "v.xyz".into(),
            }
            .to_string(),
            tf.set_weights(vec![1.0]).unwrap_err().to_string(),
        ] {
            assert!(!e.contains("--"), "{e}");
        }
    }
}
