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
/// source (`file: reason`), and the chain would repeat it.
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
        msg.push_str(&text);
    }
    msg
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
        args::Command::Bench(args::BenchCommand::Pof(a)) => cmd::pof::bench(&a, &ui),
        args::Command::Pof(c) => cmd::pof::run(&c, &ui),
    }
}
