//! What the process and the machine measure about themselves: this process's CPU time and the
//! load averages, to judge wall times on a shared machine (Linux `/proc`; `None` elsewhere).

/// CPU time (user + system) of this process so far, ms, from `/proc/self/stat` (Linux; clock
/// ticks, usually 10 ms). `None` where that file does not exist.
pub fn process_cpu_ms() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may contain spaces).
    let rest = stat.get(stat.rfind(')')? + 2..)?;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the whole line, 12 and 13 after the name.
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    // The kernel reports USER_HZ ticks, 100 per second on every mainstream Linux build.
    Some(ticks * 10.0)
}

/// The 1-minute load average as `/proc/loadavg` writes it (the report's `machine_load`).
pub fn load_average_1min() -> Option<String> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    text.split_whitespace().next().map(str::to_string)
}

/// The 1, 5 and 15 minute load averages (`/proc/loadavg`), to judge wall times on a shared machine.
pub fn load_average() -> Option<[f64; 3]> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    let mut it = text.split_whitespace().map(|v| v.parse::<f64>().ok());
    Some([it.next()??, it.next()??, it.next()??])
}
