//! The one line a generated report gives about the machine that wrote it: its CPU, the SIMD
//! features the kernels can use, the number of logical CPUs and how busy the machine was. Wall
//! times mean little without it.

/// `Machine: <CPU> (<features>), <n> logical CPUs; load average (1, 5, 15 min) <a, b, c>.`
/// Parts that cannot be read on this system are left out.
pub(crate) fn machine_line() -> String {
    let mut line = format!("Machine: {}", cpu_name().unwrap_or_else(|| std::env::consts::ARCH.to_string()));
    let features = simd_features();
    if !features.is_empty() {
        line += &format!(" ({})", features.join(", "));
    }
    if let Ok(n) = std::thread::available_parallelism() {
        line += &format!(", {n} logical CPUs");
    }
    if let Some(load) = load_average() {
        line += &format!("; load average (1, 5, 15 min) {load}");
    }
    line + "."
}

/// `/proc/cpuinfo`'s first processor entry (Linux).
fn cpuinfo() -> Option<String> {
    let text = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    Some(text.split("\n\n").next().unwrap_or_default().to_string())
}

fn cpuinfo_field<'a>(entry: &'a str, key: &str) -> Option<&'a str> {
    entry.lines().find_map(|l| {
        let (k, v) = l.split_once(':')?;
        (k.trim() == key).then(|| v.trim())
    })
}

/// The CPU's model name, with its family and model numbers where the name is generic.
fn cpu_name() -> Option<String> {
    let entry = cpuinfo()?;
    let name = cpuinfo_field(&entry, "model name")?;
    Some(match (cpuinfo_field(&entry, "cpu family"), cpuinfo_field(&entry, "model")) {
        (Some(family), Some(model)) => format!("{name}, family {family} model {model}"),
        _ => name.to_string(),
    })
}

/// The x86-64 SIMD features the kernel tiers use, as the CPU reports them.
fn simd_features() -> Vec<&'static str> {
    let Some(entry) = cpuinfo() else { return Vec::new() };
    let Some(flags) = cpuinfo_field(&entry, "flags") else { return Vec::new() };
    let flags: Vec<&str> = flags.split_whitespace().collect();
    [
        ("avx2", "AVX2"),
        ("fma", "FMA"),
        ("avx512f", "AVX-512F"),
        ("avx512_bf16", "AVX512-BF16"),
        ("amx_bf16", "AMX-BF16"),
    ]
    .into_iter()
    .filter(|(flag, _)| flags.contains(flag))
    .map(|(_, name)| name)
    .collect()
}

/// The machine's load averages as `/proc/loadavg` gives them (Linux), if readable.
fn load_average() -> Option<String> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    let fields: Vec<&str> = text.split_whitespace().take(3).collect();
    (fields.len() == 3).then(|| fields.join(", "))
}

#[cfg(test)]
mod tests {
    use super::{cpuinfo_field, machine_line};

    #[test]
    fn cpuinfo_fields_are_read_by_their_whole_key() {
        let entry = "processor\t: 0\nmodel\t\t: 207\nmodel name\t: Example CPU @ 2.10GHz\nflags\t\t: fpu avx2 fma\n";
        assert_eq!(cpuinfo_field(entry, "model"), Some("207"));
        assert_eq!(cpuinfo_field(entry, "model name"), Some("Example CPU @ 2.10GHz"));
        assert_eq!(cpuinfo_field(entry, "flags"), Some("fpu avx2 fma"));
        assert_eq!(cpuinfo_field(entry, "cpu family"), None);
    }

    #[test]
    fn the_machine_line_is_one_sentence_on_one_line() {
        let line = machine_line();
        assert!(line.starts_with("Machine: ") && line.ends_with('.') && !line.contains('\n'), "{line}");
        if cfg!(target_os = "linux") {
            assert!(line.contains("logical CPUs") && line.contains("load average"), "{line}");
        }
    }
}
