//! What the operating system says about memory, read from `/proc` (Linux; `None` elsewhere): the
//! machine's total and available memory, which marching cubes, `check` and `train` compare their
//! estimates with, and the process's peak resident memory, which the report shows. Both files are
//! `Key:   N kB` lines, read by one parser.

/// The value in bytes of the `key: N kB` line of a `/proc` status text.
fn kb_field(text: &str, key: &str) -> Option<u64> {
    text.lines().find_map(|l| {
        let rest = l.strip_prefix(key)?.strip_prefix(':')?;
        let kb: u64 = rest.trim().trim_end_matches("kB").trim().parse().ok()?;
        Some(kb * 1024)
    })
}

/// `bytes` as GiB with two decimals, for messages.
pub fn gib(bytes: f64) -> String {
    format!("{:.2} GiB", bytes / (1u64 << 30) as f64)
}

/// The machine's memory in bytes, from `/proc/meminfo`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MachineMemory {
    /// `MemAvailable`: what a new allocation can get without swapping.
    pub available: u64,
    /// `MemTotal`.
    pub total: u64,
}

impl MachineMemory {
    /// `None` where `/proc/meminfo` cannot be read (not Linux): the checks then accept.
    pub fn read() -> Option<MachineMemory> {
        MachineMemory::parse(&std::fs::read_to_string("/proc/meminfo").ok()?)
    }

    /// Parses `/proc/meminfo` text (`Key:   N kB` lines).
    pub fn parse(text: &str) -> Option<MachineMemory> {
        Some(MachineMemory {
            available: kb_field(text, "MemAvailable")?,
            total: kb_field(text, "MemTotal")?,
        })
    }
}

/// The process's peak resident memory (`VmHWM` of `/proc/self/status`) in bytes.
pub fn peak_rss() -> Option<u64> {
    kb_field(&std::fs::read_to_string("/proc/self/status").ok()?, "VmHWM")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn meminfo_parses() {
        let text = "MemTotal:       24683652 kB\nMemFree:  100 kB\nMemAvailable:   23887096 kB\n";
        let m = MachineMemory::parse(text).unwrap();
        assert_eq!(m.total, 24683652 * 1024);
        assert_eq!(m.available, 23887096 * 1024);
        assert!(MachineMemory::parse("MemTotal: 5 kB\n").is_none());
        assert!(MachineMemory::read().is_some_and(|m| m.available <= m.total) || !cfg!(target_os = "linux"));
    }

    #[test]
    fn peak_rss_reads() {
        assert_eq!(kb_field("Name:\ti2sdf\nVmHWM:\t  2048 kB\n", "VmHWM"), Some(2 << 20));
        assert!(peak_rss().is_some_and(|b| b > 0) || !cfg!(target_os = "linux"));
    }
}
