//! The schedule's TOML: parsed with serde, every value with its span (the `toml` crate's
//! `Spanned`), so that an error names the entry, the field, its line and the fix.

use super::{DEFAULT_OFF_NS, Epoch, Fault, FaultKind, FaultSchedule, KindName, SlaveRef};
use crate::config::{ConfigError, ConfigSource, line_of};
use serde::Deserialize;
use toml::Spanned;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileRepr {
    seed: Option<u64>,
    #[serde(default)]
    epoch: Epoch,
    /// Each entry's span is its `[[fault]]` header.
    #[serde(default)]
    fault: Vec<Spanned<EntryRepr>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct EntryRepr {
    at_s: Spanned<f64>,
    for_s: Option<Spanned<f64>>,
    kind: Spanned<String>,
    probability: Option<Spanned<f64>>,
    frames: Option<Spanned<u32>>,
    extra_us: Option<Spanned<f64>>,
    slave: Option<Spanned<SlaveRepr>>,
    port: Option<Spanned<u8>>,
    stall_ms: Option<Spanned<f64>>,
    step_us: Option<Spanned<f64>>,
    lag_us: Option<Spanned<f64>>,
    slaves: Option<Spanned<u16>>,
    code: Option<Spanned<i64>>,
}

impl EntryRepr {
    /// The parameters given (the keys besides `at_s`, `for_s` and `kind`), with their spans.
    fn parameters(&self) -> [(&'static str, Option<std::ops::Range<usize>>); 10] {
        fn span<T>(v: &Option<Spanned<T>>) -> Option<std::ops::Range<usize>> {
            v.as_ref().map(Spanned::span)
        }
        [
            ("probability", span(&self.probability)),
            ("frames", span(&self.frames)),
            ("extra_us", span(&self.extra_us)),
            ("slave", span(&self.slave)),
            ("port", span(&self.port)),
            ("stall_ms", span(&self.stall_ms)),
            ("step_us", span(&self.step_us)),
            ("lag_us", span(&self.lag_us)),
            ("slaves", span(&self.slaves)),
            ("code", span(&self.code)),
        ]
    }
}

#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum SlaveRepr {
    Position(i64),
    Name(String),
}

impl FaultSchedule {
    /// Parses a schedule; `file` names it in errors (which give the entry, the field and the
    /// fix).
    pub fn parse(file: &str, text: &str) -> Result<FaultSchedule, ConfigError> {
        let src = ConfigSource::new(file, text);
        let f: FileRepr = src.deserialize().map_err(|e| entry_error(text, e))?;
        let mut faults = Vec::with_capacity(f.fault.len());
        let mut lines = Vec::with_capacity(f.fault.len());
        for (n, e) in f.fault.iter().enumerate() {
            let at = EntryAt {
                src: &src,
                n,
                header_line: line_of(text, e.span().start),
                kind: None,
            };
            faults.push(at.fault(e.get_ref())?);
            lines.push(at.header_line);
        }
        Ok(FaultSchedule {
            seed: f.seed,
            epoch: f.epoch,
            faults,
            file: file.to_string(),
            lines,
        })
    }

    /// Reads and parses a schedule file, or the built-in schedule of that name (when no such
    /// file exists).
    pub fn load(path: &std::path::Path) -> Result<FaultSchedule, ConfigError> {
        let name = path.display().to_string();
        if !path.exists()
            && let Some((n, text)) = super::BUILT_IN.iter().find(|(n, _)| *n == name)
        {
            return Self::parse(n, text);
        }
        let text = crate::config::read_text(path).map_err(|mut e| {
            if e.line.is_none() {
                e.fix = format!(
                    "give the path of a fault schedule (TOML with [[fault]] entries) or a built-in one: {}",
                    super::BUILT_IN.map(|b| b.0).join(", ")
                );
            }
            e
        })?;
        Self::parse(&name, &text)
    }

    /// Whether the schedule holds faults of the master's host (see
    /// [`FaultKind::is_host_fault`]).
    pub fn has_host_faults(&self) -> bool {
        self.faults.iter().any(|f| f.kind.is_host_fault())
    }
}

/// The TOML parser's error in a schedule's words: an entry that lacks a field is named
/// (`fault[N].kind`, N counting the `[[fault]]` headers up to its line) and the fix points at
/// files that have faults (the general fix names a scenario preset, which has none).
fn entry_error(text: &str, mut e: ConfigError) -> ConfigError {
    let headers_to = |line: usize| {
        text.lines()
            .take(line)
            .filter(|l| l.trim_start().starts_with("[[fault]]"))
            .count()
    };
    // A misspelt field of an entry: which entry, as every other entry error says.
    if e.message.contains("unknown field")
        && let Some(line) = e.line
        && headers_to(line) > 0
        && !e.field.is_empty()
    {
        e.field = format!("fault[{}].{}", headers_to(line) - 1, e.field);
        return e;
    }
    let Some(name) = e
        .message
        .split_once("missing field `")
        .and_then(|(_, r)| r.split_once('`'))
        .map(|(n, _)| n.to_string())
    else {
        return e;
    };
    if let Some(line) = e.line
        && e.field.starts_with("fault")
    {
        let headers = headers_to(line);
        if headers > 0 {
            e.field = format!("fault[{}].{name}", headers - 1);
        }
    }
    let example = match name.as_str() {
        "at_s" => "at_s = 20.0 (seconds after the epoch)",
        "kind" => "kind = \"loss\" (or another kind)",
        _ => "it",
    };
    e.fix = format!(
        "add {example} to the entry: every [[fault]] entry needs at_s and kind (presets/faults-demo.toml and the book's reference, Fault schedules, show every kind and field)"
    );
    e
}

/// Parses one fault entry given on its own (a control command's), as a `[[fault]]` entry of a
/// file is parsed: the same checks, the same words. `at_s` may be absent (the returned
/// fault's `at_ns` is then 0; the caller, which can tell by the table, takes it as "now").
/// An error reads `key: what is wrong; fix: what to do`.
pub fn parse_fault_entry(table: &toml::Table) -> Result<Fault, String> {
    let mut entry = table.clone();
    entry.entry("at_s").or_insert(toml::Value::Float(0.0));
    let mut file = toml::Table::new();
    file.insert(
        "fault".into(),
        toml::Value::Array(vec![toml::Value::Table(entry)]),
    );
    let text = toml::to_string(&file).map_err(|e| format!("the entry cannot be read: {e}"))?;
    match FaultSchedule::parse("fault", &text) {
        Ok(s) => Ok(s.faults[0]),
        Err(e) => {
            let key = e.field.strip_prefix("fault[0].").unwrap_or(&e.field);
            let mut m = format!("{key}: {}", e.message);
            if !e.fix.is_empty() {
                m += &format!("; fix: {}", e.fix);
            }
            Err(m)
        }
    }
}

/// The `n`-th entry of a file, for its errors: `fault[n].key` at the key's line (the header's
/// for a key the entry lacks).
#[derive(Clone, Copy)]
struct EntryAt<'a> {
    src: &'a ConfigSource<'a>,
    n: usize,
    header_line: usize,
    /// The entry's kind, once known (for messages).
    kind: Option<&'static str>,
}

impl EntryAt<'_> {
    fn err(
        &self,
        key: &str,
        at: Option<std::ops::Range<usize>>,
        message: String,
        fix: &str,
    ) -> ConfigError {
        let line = at.map_or(self.header_line, |s| line_of(self.src.text, s.start));
        self.src
            .at(Some(line), format!("fault[{}].{key}", self.n), message, fix)
    }

    /// The error of a value the entry gave.
    fn bad<T>(&self, key: &str, v: &Spanned<T>, message: String, fix: &str) -> ConfigError {
        self.err(key, Some(v.span()), message, fix)
    }

    /// The error of a key the entry lacks.
    fn missing(&self, key: &str, message: String, fix: &str) -> ConfigError {
        self.err(key, None, message, fix)
    }

    fn seconds(&self, key: &str, v: &Spanned<f64>) -> Result<u64, ConfigError> {
        let s = *v.get_ref();
        if !s.is_finite() || !(0.0..=1e9).contains(&s) {
            return Err(self.bad(
                key,
                v,
                format!("{s} is not a time"),
                "give seconds, 0 or more",
            ));
        }
        Ok((s * 1e9).round() as u64)
    }

    fn fault(&self, e: &EntryRepr) -> Result<Fault, ConfigError> {
        let at_ns = self.seconds("at_s", &e.at_s)?;
        let for_ns = e
            .for_s
            .as_ref()
            .map(|v| self.seconds("for_s", v))
            .transpose()?;
        let kind_name: KindName = e.kind.get_ref().parse().map_err(|_| {
            self.bad(
                "kind",
                &e.kind,
                format!("unknown fault kind \"{}\"", e.kind.get_ref()),
                &format!("use one of {}", KindName::list()),
            )
        })?;
        let this = EntryAt {
            kind: Some(kind_name.as_str()),
            ..*self
        };
        let at = &this;
        // Parameters a kind does not take are refused: a typo would otherwise be silently
        // ignored.
        let allowed = kind_name.parameters();
        if let Some((k, span)) = e
            .parameters()
            .into_iter()
            .find(|(k, s)| s.is_some() && !allowed.contains(k))
        {
            return Err(self.err(
                k,
                span,
                format!("kind \"{kind_name}\" takes no {k}"),
                &format!("remove it; \"{kind_name}\" takes {}", allowed.join(", ")),
            ));
        }
        let kind = at.kind(kind_name, e)?;
        let for_ns = match kind {
            FaultKind::PowerCycle { .. } => Some(for_ns.unwrap_or(DEFAULT_OFF_NS)),
            _ => for_ns,
        };
        Ok(Fault {
            at_ns,
            for_ns,
            kind,
        })
    }

    /// The kind's own parameters, checked.
    fn kind(&self, kind: KindName, e: &EntryRepr) -> Result<FaultKind, ConfigError> {
        Ok(match kind {
            KindName::Loss => {
                let (probability, burst) = self.probability(kind, e)?;
                FaultKind::Loss { probability, burst }
            }
            KindName::Corrupt => {
                let (probability, burst) = self.probability(kind, e)?;
                FaultKind::Corrupt { probability, burst }
            }
            KindName::Delay => FaultKind::Delay {
                extra_ns: self.not_negative_us(
                    "extra_us",
                    &e.extra_us,
                    None,
                    "give the extra delay in microseconds, 0 or more",
                )?,
            },
            KindName::PowerCycle => FaultKind::PowerCycle {
                slave: self.slave(kind, e)?,
            },
            KindName::AlError => {
                let code = self.al_code(e)?;
                FaultKind::AlError {
                    slave: self.slave(kind, e)?,
                    code,
                }
            }
            KindName::LinkDown => {
                let port = self.port(e)?;
                FaultKind::LinkDown {
                    slave: self.slave(kind, e)?,
                    port,
                }
            }
            KindName::HostStall => {
                let ms = self.finite("stall_ms", &e.stall_ms, None)?;
                if ms <= 0.0 {
                    let v = e.stall_ms.as_ref().expect("a finite value was given");
                    return Err(self.bad(
                        "stall_ms",
                        v,
                        format!("{ms} is not a stall"),
                        "give the stall in milliseconds, more than 0",
                    ));
                }
                FaultKind::HostStall {
                    stall_ns: (ms * 1e6).round() as u64,
                }
            }
            KindName::ClockStep => FaultKind::ClockStep {
                step_ns: (self.finite("step_us", &e.step_us, None)? * 1e3).round() as i64,
            },
            KindName::SecondResponder => FaultKind::SecondResponder {
                lag_ns: self.not_negative_us(
                    "lag_us",
                    &e.lag_us,
                    Some(5.0),
                    "give the copy's lag in microseconds, 0 or more",
                )?,
            },
            KindName::HotConnect => match &e.slaves {
                Some(n) if *n.get_ref() >= 1 => FaultKind::HotConnect {
                    slaves: *n.get_ref(),
                },
                _ => {
                    return Err(self.err(
                        "slaves",
                        e.slaves.as_ref().map(Spanned::span),
                        format!("kind \"{kind}\" needs how many slaves appear, 1 or more"),
                        "add slaves = 2 (the last two slaves of the network, absent until at_s)",
                    ));
                }
            },
        })
    }

    /// A finite number of at most 1e12 in magnitude; `default` where the entry gives none
    /// (without one, a missing value is refused, naming the key the kind needs).
    fn finite(
        &self,
        key: &str,
        v: &Option<Spanned<f64>>,
        default: Option<f64>,
    ) -> Result<f64, ConfigError> {
        let x = match (v, default) {
            (Some(v), _) => *v.get_ref(),
            (None, Some(d)) => d,
            (None, None) => {
                let kind = self.kind.unwrap_or("this kind");
                return Err(self.missing(
                    key,
                    format!("kind \"{kind}\" needs {key}"),
                    &format!("add {key} = <number> to the entry"),
                ));
            }
        };
        if !x.is_finite() || x.abs() > 1e12 {
            return Err(self.err(
                key,
                v.as_ref().map(Spanned::span),
                format!("{x} is out of range"),
                "give a finite number",
            ));
        }
        Ok(x)
    }

    /// Microseconds, 0 or more, as ns.
    fn not_negative_us(
        &self,
        key: &str,
        v: &Option<Spanned<f64>>,
        default: Option<f64>,
        fix: &str,
    ) -> Result<u64, ConfigError> {
        let us = self.finite(key, v, default)?;
        if us < 0.0 {
            return Err(self.err(
                key,
                v.as_ref().map(Spanned::span),
                format!("{us} is negative"),
                fix,
            ));
        }
        Ok((us * 1e3).round() as u64)
    }

    /// Loss and corruption: a probability while the window lasts, or a burst of frames.
    fn probability(
        &self,
        kind: KindName,
        e: &EntryRepr,
    ) -> Result<(f64, Option<u32>), ConfigError> {
        match (&e.probability, &e.frames) {
            (Some(_), Some(k)) => Err(self.bad(
                "frames",
                k,
                "both probability and frames are given".into(),
                "give probability (random loss while it lasts) or frames (a burst), not both",
            )),
            (Some(p), None) if (0.0..=1.0).contains(p.get_ref()) => Ok((*p.get_ref(), None)),
            (Some(p), None) => Err(self.bad(
                "probability",
                p,
                format!("{} is not a probability", p.get_ref()),
                "give a number from 0 to 1, e.g. 0.1 for 10 %",
            )),
            (None, Some(k)) if *k.get_ref() == 0 => Err(self.bad(
                "frames",
                k,
                "a burst of 0 frames".into(),
                "give 1 or more frames",
            )),
            (None, Some(k)) => Ok((1.0, Some(*k.get_ref()))),
            (None, None) => Err(self.missing(
                "probability",
                format!("kind \"{kind}\" needs probability or frames"),
                "add probability = 0.1 (random) or frames = 10 (a burst)",
            )),
        }
    }

    fn slave(&self, kind: KindName, e: &EntryRepr) -> Result<SlaveRef, ConfigError> {
        const FIX: &str =
            "give the slave's position, 1 for the one next to the master, or \"reference\"";
        let Some(v) = &e.slave else {
            return Err(self.missing(
                "slave",
                format!("kind \"{kind}\" needs the slave it hits"),
                "add slave = 3 (network position, 1 = next to the master) or slave = \"reference\"",
            ));
        };
        match v.get_ref() {
            SlaveRepr::Position(p) if (1..=65_535).contains(p) => {
                Ok(SlaveRef::Position(*p as usize - 1))
            }
            SlaveRepr::Name(s) if s == "reference" => Ok(SlaveRef::Reference),
            SlaveRepr::Position(p) => {
                Err(self.bad("slave", v, format!("{p} is no network position"), FIX))
            }
            SlaveRepr::Name(s) => Err(self.bad("slave", v, format!("\"{s}\" names no slave"), FIX)),
        }
    }

    fn al_code(&self, e: &EntryRepr) -> Result<u16, ConfigError> {
        const FIX: &str = "give a code from 0x0001 to 0xFFFF, e.g. 0x001A (synchronization error)";
        let Some(v) = &e.code else {
            return Ok(0x001A);
        };
        match u16::try_from(*v.get_ref()) {
            Ok(0) => Err(self.bad("code", v, "0 is \"no error\"".to_string(), FIX)),
            Ok(code) => Ok(code),
            Err(_) => Err(self.bad(
                "code",
                v,
                format!("{} is no AL status code", v.get_ref()),
                FIX,
            )),
        }
    }

    fn port(&self, e: &EntryRepr) -> Result<u8, ConfigError> {
        match &e.port {
            None => Ok(1),
            Some(p) if *p.get_ref() <= 3 => Ok(*p.get_ref()),
            Some(p) => Err(self.bad(
                "port",
                p,
                format!("port {} does not exist", p.get_ref()),
                "give a port from 0 to 3 (1: the one to the next slave of a line)",
            )),
        }
    }
}
