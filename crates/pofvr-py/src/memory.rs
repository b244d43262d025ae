//! The `memory` entry of a frame's statistics: what `pofvr render --stats` reports for its
//! one process, read from `/proc/self/status` (zeros where that file does not exist).

/// `memory` as the command line's `--stats` writes it: one entry, rank 0.
pub(crate) fn status_json() -> serde_json::Value {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let bytes = |key: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))
            .and_then(|v| v.split_whitespace().next()?.parse::<u64>().ok())
            .map_or(0, |k| k * 1024)
    };
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_owned())
        .unwrap_or_default();
    serde_json::json!([{
        "rank": 0,
        "host": host,
        "vm_rss_bytes": bytes("VmRSS"),
        "vm_hwm_bytes": bytes("VmHWM"),
        "rss_anon_bytes": bytes("RssAnon"),
        "rss_file_bytes": bytes("RssFile"),
        "brick_copy_bytes": 0,
    }])
}
