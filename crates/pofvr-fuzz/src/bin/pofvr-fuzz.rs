//! `pofvr-fuzz TARGET COUNT [--seed S] [--time-limit-ms MS] [--only N] [--corpus DIR]
//! [--findings DIR]`: feeds COUNT mutated inputs to TARGET (`all` for every target) and
//! reports inputs per second. A panic, an input running past the time limit, or an
//! allocation past what the input justifies is a finding: the input is saved under the
//! findings folder with its index (replay it with `--only N`) and the run exits 1.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use pofvr_fuzz::alloc::{self, Capped};
use pofvr_fuzz::target::{self, Scratch, Target, TARGETS};

#[global_allocator]
static ALLOC: Capped = Capped;

/// Inputs longer than this are cut: the seeds are tiny and a parser's cost is in its
/// header, not in megabytes of voxels.
const MAX_LEN: usize = 64 << 10;

struct Opts {
    targets: Vec<&'static Target>,
    count: u64,
    seed: u64,
    time_limit: Duration,
    only: Option<u64>,
    corpus: PathBuf,
    findings: PathBuf,
}

fn usage() -> ! {
    let names: Vec<&str> = TARGETS.iter().map(|t| t.name).collect();
    eprintln!(
        "usage: pofvr-fuzz TARGET COUNT [--seed S] [--time-limit-ms MS] [--only N] [--corpus DIR] [--findings DIR]\n  TARGET: all or one of {}",
        names.join(", ")
    );
    std::process::exit(2);
}

fn opts() -> Opts {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        usage();
    }
    let targets = if args[0] == "all" {
        TARGETS.iter().collect()
    } else {
        vec![target::by_name(&args[0]).unwrap_or_else(|| usage())]
    };
    let num = |s: &str| {
        s.replace('_', "")
            .parse::<u64>()
            .unwrap_or_else(|_| usage())
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut o = Opts {
        targets,
        count: num(&args[1]),
        seed: 1,
        time_limit: Duration::from_millis(2000),
        only: None,
        corpus: root.join("corpus"),
        findings: root.join("findings"),
    };
    let mut it = args[2..].iter();
    while let Some(a) = it.next() {
        let v = it.next().unwrap_or_else(|| usage());
        match a.as_str() {
            "--seed" => o.seed = num(v),
            "--time-limit-ms" => o.time_limit = Duration::from_millis(num(v)),
            "--only" => o.only = Some(num(v)),
            "--corpus" => o.corpus = v.into(),
            "--findings" => o.findings = v.into(),
            _ => usage(),
        }
    }
    o
}

/// The input being fed, and since when (ms after [`EPOCH`]; 0 when none), for the watchdog.
static CURRENT: Mutex<(String, u64, Vec<u8>)> = Mutex::new((String::new(), 0, Vec::new()));
static STARTED_MS: AtomicU64 = AtomicU64::new(0);

fn save(findings: &Path, target: &str, kind: &str, n: u64, data: &[u8]) -> PathBuf {
    let _ = std::fs::create_dir_all(findings);
    let p = findings.join(format!("{target}-{kind}-{n}"));
    let _ = std::fs::write(&p, data);
    p
}

/// Ends the process when one input runs past the limit: a parser stuck in a loop cannot be
/// interrupted from outside its thread.
fn watchdog(epoch: Instant, limit: Duration, findings: PathBuf) {
    std::thread::spawn(move || loop {
        std::thread::sleep(Duration::from_millis(50));
        let t0 = STARTED_MS.load(Ordering::SeqCst);
        let now = epoch.elapsed().as_millis() as u64;
        if t0 != 0 && now.saturating_sub(t0) > limit.as_millis() as u64 {
            let cur = CURRENT.lock().unwrap_or_else(|e| e.into_inner());
            let p = save(&findings, &cur.0, "timeout", cur.1, &cur.2);
            eprintln!(
                "FINDING {}: input {} ran past {} ms; saved as {}",
                cur.0,
                cur.1,
                limit.as_millis(),
                p.display()
            );
            std::process::exit(1);
        }
    });
}

fn seeds(dir: &Path) -> Vec<Vec<u8>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("corpus entry").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    let seeds: Vec<Vec<u8>> = files
        .iter()
        .map(|p| std::fs::read(p).expect("seed"))
        .collect();
    assert!(!seeds.is_empty(), "{}: no seeds", dir.display());
    seeds
}

fn main() {
    let o = opts();
    let epoch = Instant::now();
    watchdog(epoch, o.time_limit, o.findings.clone());
    // Findings are reported by the runner; the default hook would print every caught panic.
    std::panic::set_hook(Box::new(|_| {}));
    let mut failed = false;
    for t in &o.targets {
        let seeds = seeds(&t.corpus(&o.corpus));
        let scratch = Scratch::new();
        let range: Box<dyn Iterator<Item = u64>> = match o.only {
            Some(n) => Box::new(std::iter::once(n)),
            None => Box::new(0..o.count),
        };
        let start = Instant::now();
        let (mut fed, mut accepted, mut findings, mut slowest) = (0u64, 0u64, 0u64, Duration::ZERO);
        for n in range {
            // Each seed first, unmutated.
            let data = if (n as usize) < seeds.len() {
                seeds[n as usize].clone()
            } else {
                pofvr_fuzz::mutate::input(&seeds, o.seed, n, MAX_LEN)
            };
            {
                let mut cur = CURRENT.lock().unwrap_or_else(|e| e.into_inner());
                *cur = (t.name.to_owned(), n, data.clone());
            }
            let t0 = Instant::now();
            STARTED_MS.store(epoch.elapsed().as_millis().max(1) as u64, Ordering::SeqCst);
            alloc::arm(t.allocation_limit(data.len()));
            let r = std::panic::catch_unwind(|| t.run(&scratch, &data));
            let over = alloc::disarm();
            STARTED_MS.store(0, Ordering::SeqCst);
            slowest = slowest.max(t0.elapsed());
            fed += 1;
            accepted += u64::from(matches!(r, Ok(true)));
            let kind = match (r, over) {
                (Err(p), _) => {
                    let msg = p
                        .downcast_ref::<String>()
                        .cloned()
                        .or_else(|| p.downcast_ref::<&str>().map(|s| (*s).to_owned()))
                        .unwrap_or_default();
                    Some(format!("panic: {msg}"))
                }
                (Ok(_), Some(size)) => Some(format!(
                    "allocation of {size} bytes for a {}-byte input (limit {})",
                    data.len(),
                    t.allocation_limit(data.len())
                )),
                (Ok(_), None) => None,
            };
            if let Some(kind) = kind {
                findings += 1;
                let tag = if kind.starts_with("panic") {
                    "panic"
                } else {
                    "alloc"
                };
                let p = save(&o.findings, t.name, tag, n, &data);
                eprintln!(
                    "FINDING {} input {n}: {kind}; saved as {}",
                    t.name,
                    p.display()
                );
                if findings >= 20 {
                    eprintln!("{}: stopping after 20 findings", t.name);
                    break;
                }
            }
        }
        let secs = start.elapsed().as_secs_f64();
        println!(
            "{}: {fed} inputs ({accepted} accepted) in {secs:.1} s ({:.0}/s), {} seeds, slowest input {:.1} ms, {findings} findings",
            t.name,
            fed as f64 / secs.max(1e-9),
            seeds.len(),
            slowest.as_secs_f64() * 1e3
        );
        failed |= findings > 0;
    }
    std::process::exit(i32::from(failed));
}
