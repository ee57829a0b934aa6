//! Segment descriptions in TOML, with errors that name the file, line, field and fix.
//!
//! ```toml
//! [segment]
//! [[segment.slave]]
//! name = "drive-1"
//! model = "servo-mii"        # servo-mii | servo-mii-dc32 | ebus-terminal | ebus-terminal-no-dc
//!                            # | junction-mii; device families: et1100-coupler | et1200-terminal
//!                            # | et1200-terminal-receive-times | lan9252 | akd; real devices:
//!                            # ek1100 | el2828 | el2889
//! device = "servo-drive"     # servo-drive (default) | coupler (default of junction-mii and
//!                            # the et1100/et1200 families) | ek1100 | el2828 | el2889 (the
//!                            # default of the model of the same name);
//!                            # with `esi`: the ESI device's type name
//! # esi = "drives.xml"       # an ESI file (ETG.2000) describing the device, relative to this
//!                            # file's folder; `device` selects one of its devices by its
//!                            # <Type> text and may be left out when the file has one
//! upstream = "master"        # "master" or the name of a slave listed before this one
//! upstream_port = 1          # port of the upstream slave (not used for the master)
//! entry_port = 0             # this slave's port towards the master
//! cable_m = 2.0
//! ppm = 12.4                 # crystal error
//! # Optional, as `ecsync run --save-network` writes them from a real network's SII:
//! # vendor_id = 0x00000e5c, product_code = 0x00004024, revision = 0x00010000,
//! # device_name = "..." (at most 64 bytes): override the device's identity and SII name.
//! # forwarding_delay_ns, processing_delay_ns, link_phy_delay_ns: override the model's delays.
//! ```
//!
//! ESC models ([`EscModel`]; 0x0008 as real chips of each class show it, see
//! [`EscModel::features`]):
//! - `servo-mii`: ET1100-class servo drive, MII ports 0 and 1 to 100BASE-TX PHYs, 64-bit DC,
//!   features 0x00FC.
//! - `servo-mii-dc32`: the same drive with a 32-bit DC unit, as the Kollmorgen AKD (ESC type
//!   0x04, features 0x0184): its system time wraps every 4.295 s.
//! - `ebus-terminal`: ET1200-class EBUS terminal, 64-bit DC, features 0x01FC.
//! - `ebus-terminal-no-dc`: the same without a DC unit (features 0x01F0).
//! - `junction-mii`: ET1100-class junction with four MII ports, 64-bit DC, features 0x00FC.
//!
//! Device families (`crate::model::families`: each value from a capture of real hardware or
//! a datasheet; registers, resources, hop delays, SII timing and read size, AL behaviour,
//! mailbox response time):
//! - `et1100-coupler`: an ET1100 coupler like the EK1100 (MII in, EBUS to terminals, MII out),
//!   device emulation, 64-bit DC.
//! - `et1200-terminal`: an ET1200 EBUS terminal like the EL2889, device emulation, 64-bit DC.
//! - `et1200-terminal-receive-times`: the same with receive times only, like the EL2828.
//! - `lan9252`: a Microchip LAN9252 board (two 100BASE-TX ports, 64-bit DC), a firmware that
//!   takes AL control 17.5 ms after a write and refuses another write until then.
//! - `akd`: a microcontroller drive like the Kollmorgen AKD (two MII ports, 32-bit DC), a
//!   firmware that takes AL control 4.5 ms after a write, 4-byte SII reads.
//!
//! Real devices as the captures of real hardware show them ([`crate::catalog`]), each a model
//! and a device of the same name (the device is the model's default): `ek1100` (the coupler,
//! an et1100-coupler), `el2828` (8 digital outputs, an et1200-terminal with receive times
//! only), `el2889` (16 digital outputs, an et1200-terminal with a system time); the
//! terminals' outputs at the digital output register 0x0F00.

use crate::catalog;
use crate::clock::CrystalParams;
use crate::model::{DcSupport, DeviceInfo, EscModel, PortKind};
use crate::segment::{SlaveSpec, Upstream};
use serde::Deserialize;
use std::collections::HashMap;

use std::path::{Path, PathBuf};
use std::sync::Arc;

mod crystals;
mod source;
use source::key_line_in;
pub use source::{ConfigError, ConfigSource, Problem, key_line, line_of, read_text, toml_error};

/// The `[segment]` table.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmentConfig {
    /// Seed of the crystals' wander processes (each slave adds its index).
    #[serde(default)]
    pub seed: u64,
    /// The slaves (none is an error [`SegmentConfig::to_specs`] names, with its fix).
    #[serde(default)]
    pub slave: Vec<toml::Spanned<SlaveConfig>>,
}

/// One `[[segment.slave]]` table.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SlaveConfig {
    /// Name, unique in the segment.
    pub name: String,
    /// ESC model.
    #[serde(default = "default_model")]
    pub model: String,
    /// Device: a built-in one (`servo-drive`, the default, or `coupler`, the default of a
    /// `junction-mii`), or with `esi` the type name of one of the file's devices.
    #[serde(default)]
    pub device: Option<String>,
    /// An ESI file describing the device, relative to the configuration file's folder.
    #[serde(default)]
    pub esi: Option<String>,
    /// "master" or the name of an earlier slave.
    pub upstream: String,
    /// Port of the upstream slave.
    #[serde(default = "default_upstream_port")]
    pub upstream_port: u8,
    /// This slave's port towards the master.
    #[serde(default)]
    pub entry_port: u8,
    /// Cable to the upstream device, m.
    #[serde(default = "default_cable")]
    pub cable_m: f64,
    /// Crystal error, ppm.
    #[serde(default)]
    pub ppm: f64,
    /// Crystal wander, ppm per sqrt(s).
    #[serde(default = "default_wander")]
    pub wander_ppm_per_sqrt_s: f64,
    /// Local time at power-up (simulation start), ns.
    #[serde(default)]
    pub power_up_ns: Option<u64>,
    /// The drive's SYNC PLL limit on |0x092C|, us: past it the drive leaves OP with AL status
    /// code 0x0032 (PLL error), as drives whose PLL cannot follow a reference pushed by bus
    /// shift do. Absent: no limit.
    #[serde(default)]
    pub pll_limit_us: Option<f64>,
    /// This slave's port cabled back to the master's second port (cable redundancy: the
    /// segment is a ring; a line's last slave, port 1). Absent: none.
    #[serde(default)]
    pub ring_port: Option<u8>,
    /// The ring cable's length, m (with `ring_port`).
    #[serde(default = "default_cable")]
    pub ring_cable_m: f64,
    /// Samples per cycle of an `oversampling-terminal` (1-100; absent: 4): SYNC0 runs that
    /// many times a cycle, SYNC1 once.
    #[serde(default)]
    pub oversampling: Option<i64>,
    /// Serial number.
    #[serde(default)]
    pub serial: Option<u32>,
    /// Forwarding delay override, ns.
    #[serde(default)]
    pub forwarding_delay_ns: Option<f64>,
    /// Processing delay override, ns.
    #[serde(default)]
    pub processing_delay_ns: Option<f64>,
    /// Link PHY delay override, ns.
    #[serde(default)]
    pub link_phy_delay_ns: Option<f64>,
    /// Vendor ID override (SII), e.g. as a twin of a real network read it.
    #[serde(default)]
    pub vendor_id: Option<u32>,
    /// Product code override (SII).
    #[serde(default)]
    pub product_code: Option<u32>,
    /// Revision override (SII).
    #[serde(default)]
    pub revision: Option<u32>,
    /// The device name in the SII strings, overriding the device's (at most 64 bytes).
    #[serde(default)]
    pub device_name: Option<String>,
}

/// The ESC models a file names, with the model each name builds: the calibrated models first
/// (a real ESC whose registers fit one of them exactly is given it, see
/// [`model_for_registers`]), then the device families, then the real devices.
pub const MODEL_NAMES: [&str; 13] = [
    "servo-mii",
    "servo-mii-dc32",
    "ebus-terminal",
    "ebus-terminal-no-dc",
    "junction-mii",
    "et1100-coupler",
    "et1200-terminal",
    "et1200-terminal-receive-times",
    "lan9252",
    "akd",
    "ek1100",
    "el2828",
    "el2889",
];

/// A real device of [`crate::catalog`]: its name, its model, its device with a serial number.
type CatalogEntry = (&'static str, fn() -> EscModel, fn(u32) -> DeviceInfo);

/// The real devices of [`crate::catalog`]: a model and a device each, by the same name.
const CATALOG: [CatalogEntry; 3] = [
    ("ek1100", catalog::ek1100_model, catalog::ek1100),
    ("el2828", catalog::el2828_model, catalog::el2828),
    ("el2889", catalog::el2889_model, catalog::el2889),
];

/// The model a name in a file builds (`None`: no such model).
pub fn model_named(name: &str) -> Option<EscModel> {
    Some(match name {
        "servo-mii" => EscModel::servo_mii(),
        "servo-mii-dc32" => EscModel::servo_mii_dc32(),
        "ebus-terminal" => EscModel::ebus_terminal(DcSupport::Full64),
        "ebus-terminal-no-dc" => EscModel::ebus_terminal(DcSupport::None),
        "junction-mii" => EscModel::junction_mii(),
        "et1100-coupler" => EscModel::et1100_coupler(),
        "et1200-terminal" => EscModel::et1200_terminal(DcSupport::Full64),
        "et1200-terminal-receive-times" => EscModel::et1200_terminal(DcSupport::ReceiveTimes),
        "lan9252" => EscModel::lan9252(),
        "akd" => EscModel::akd_drive(),
        _ => return CATALOG.iter().find(|c| c.0 == name).map(|c| c.1()),
    })
}

/// The device a model's slaves are when a file names none: a coupler for junctions,
/// couplers and EBUS terminals of the families (they drive no motor), else a servo drive.
fn default_device(model: &str) -> &'static str {
    match model {
        "junction-mii" | "et1100-coupler" | "et1200-terminal" | "et1200-terminal-receive-times" => {
            "coupler"
        }
        // A real device's model: that device.
        m => CATALOG
            .iter()
            .find(|c| c.0 == m)
            .map_or("servo-drive", |c| c.0),
    }
}

/// How well [`model_for_registers`] matched a real ESC's registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelMatch {
    /// ESC type (0x0000), features (0x0008) and port descriptor (0x0007) are the model's.
    Exact,
    /// Ports and DC width are the model's; the ESC type or other feature bits differ.
    Ports,
    /// Nothing fits well: the model with the most ports of the same kinds and the same DC.
    Nearest,
}

/// The ESC model whose registers a real ESC's are: ESC type (0x0000), features (0x0008), port
/// descriptor (0x0007). Exact when every model register agrees; else the model with the same
/// port kinds and DC width (64-bit, 32-bit, none: features bits 2 and 3); else the one that
/// agrees on most ports, DC first.
pub fn model_for_registers(
    esc_type: u8,
    features: u16,
    port_descriptor: u8,
) -> (&'static str, ModelMatch) {
    use ecsync_wire::register::features as f;
    let dc_bits = features & (f::DC | f::DC_64BIT);
    let models = MODEL_NAMES.map(|n| (n, model_named(n).unwrap_or_else(EscModel::servo_mii)));
    if let Some((n, _)) = models.iter().find(|(_, m)| {
        m.esc_type == esc_type && m.features() == features && m.port_descriptor() == port_descriptor
    }) {
        return (n, ModelMatch::Exact);
    }
    if let Some((n, _)) = models.iter().find(|(_, m)| {
        m.port_descriptor() == port_descriptor && m.features() & (f::DC | f::DC_64BIT) == dc_bits
    }) {
        return (n, ModelMatch::Ports);
    }
    let score = |m: &EscModel| {
        let ports = (0..4)
            .filter(|p| (m.port_descriptor() >> (2 * p)) & 3 == (port_descriptor >> (2 * p)) & 3)
            .count();
        let dc = usize::from(m.features() & (f::DC | f::DC_64BIT) == dc_bits);
        dc * 10 + ports
    };
    let best = models
        .iter()
        .max_by_key(|(_, m)| score(m))
        .map_or("servo-mii", |(n, _)| n);
    (best, ModelMatch::Nearest)
}

fn default_model() -> String {
    "servo-mii".into()
}
fn default_upstream_port() -> u8 {
    1
}
fn default_cable() -> f64 {
    1.0
}
fn default_wander() -> f64 {
    crate::clock::CRYSTAL_WANDER_PPM_PER_SQRT_S
}

/// Most slaves a segment may have (the 16-bit auto-increment address space).
pub const MAX_SLAVES: usize = 65_535;

impl SegmentConfig {
    /// Builds the slave specs, checking every field. `file` and `text` locate errors.
    pub fn to_specs(
        &self,
        file: &str,
        text: &str,
        path: &str,
    ) -> Result<Vec<SlaveSpec>, ConfigError> {
        let src = ConfigSource::new(file, text);
        self.check_slave_count(&src, path)?;
        let mut names: Vec<&str> = Vec::with_capacity(self.slave.len());
        let mut esi_files = EsiFiles::default();
        let mut specs = Vec::with_capacity(self.slave.len());
        for (i, sp) in self.slave.iter().enumerate() {
            let at = SlaveAt {
                src: &src,
                path,
                i,
                span: sp.span(),
                line: Some(line_of(text, sp.span().start)),
            };
            let spec = self.slave_spec(sp.get_ref(), &at, &names, &specs, &mut esi_files)?;
            specs.push(spec);
            names.push(&sp.get_ref().name);
        }
        let seg = match crate::Segment::new(&specs) {
            Ok(seg) => seg,
            Err(e) => {
                return Err(src.at(
                    None,
                    format!("{path}.slave"),
                    e.to_string(),
                    "connect every slave once, one of them to the master",
                ));
            }
        };
        self.check_crystals_lockable(&src, path, &seg, &specs)?;
        Ok(specs)
    }

    /// The segment has at least one slave, and no more than the auto-increment addresses.
    fn check_slave_count(&self, src: &ConfigSource<'_>, path: &str) -> Result<(), ConfigError> {
        if self.slave.is_empty() {
            return Err(src.at(
                None,
                format!("{path}.slave"),
                "the segment has no slaves",
                "add at least one [[segment.slave]] table (name, model, upstream; presets/paper-2024.toml describes six drives)",
            ));
        }
        if self.slave.len() > MAX_SLAVES {
            return Err(src.at(
                None,
                format!("{path}.slave"),
                format!(
                    "{} slaves, more than the {MAX_SLAVES} auto-increment addresses",
                    self.slave.len()
                ),
                "split the network into segments of at most 65535 slaves",
            ));
        }
        Ok(())
    }

    /// Slave `s` (at `at`) as a spec, its fields checked in the order a file's reader meets
    /// them: its name against the `names` of the slaves before it (`specs`), its model, its
    /// device and identity, the model's delays, cable and crystal, its ports and upstream.
    fn slave_spec(
        &self,
        s: &SlaveConfig,
        at: &SlaveAt<'_>,
        names: &[&str],
        specs: &[SlaveSpec],
        esi_files: &mut EsiFiles,
    ) -> Result<SlaveSpec, ConfigError> {
        if names.contains(&s.name.as_str()) {
            return Err(at.error(
                at.line,
                "name",
                format!("\"{}\" is used twice", s.name),
                "give every slave its own name",
            ));
        }
        let Some(mut model) = model_named(&s.model) else {
            return Err(at.error(
                at.line,
                "model",
                format!("unknown ESC model \"{}\"", s.model),
                &format!("use one of {}", MODEL_NAMES.join(", ")),
            ));
        };
        let serial = s.serial.unwrap_or(at.i as u32 + 1);
        let mut device = s.device(serial, at, esi_files)?;
        s.override_identity(&mut device, at)?;
        device.pll_limit_ns = s.pll_limit_ns(at)?;
        s.check_oversampling(&device, at)?;
        s.override_delays(&mut model, at)?;
        s.check_cable_and_crystal(at)?;
        let upstream = s.upstream(&model, names, specs, at)?;
        let ring = s.ring_cable(&model, at)?;
        Ok(SlaveSpec {
            model,
            device,
            crystal: CrystalParams {
                ppm: s.ppm,
                wander_ppm_per_sqrt_s: s.wander_ppm_per_sqrt_s,
                wander_step_ps: crate::clock::DEFAULT_WANDER_STEP_PS,
                initial_local_ns: s
                    .power_up_ns
                    .unwrap_or(1_000_000_000 + 123_456_789 * at.i as u64),
                seed: self.seed.wrapping_add(at.i as u64),
            },
            upstream,
            entry_port: s.entry_port,
            cable_m: s.cable_m,
            ring,
        })
    }
}

/// Where slave `i`'s table stands in its file, for the errors of its fields.
struct SlaveAt<'a> {
    src: &'a ConfigSource<'a>,
    /// The segment table's path (`segment`).
    path: &'a str,
    i: usize,
    /// The table's span (its header: see [`key_line_in`]).
    span: std::ops::Range<usize>,
    /// The table header's line.
    line: Option<usize>,
}

impl SlaveAt<'_> {
    /// The full name of the slave's field `name`.
    fn field(&self, name: &str) -> String {
        format!("{}.slave[{}].{name}", self.path, self.i)
    }

    /// The line of the slave's `key = ...`, else its table header's.
    fn key_line(&self, key: &str) -> Option<usize> {
        key_line_in(self.src.text, self.span.clone(), key).or(self.line)
    }

    /// An error in the slave's field `name`, at `line`.
    fn error(&self, line: Option<usize>, name: &str, message: String, fix: &str) -> ConfigError {
        self.src.at(line, self.field(name), message, fix)
    }
}

/// A port that exists on model `m`.
fn port_ok(m: &EscModel, p: u8) -> bool {
    p < 4 && m.ports[usize::from(p)] != PortKind::None
}

impl SlaveConfig {
    /// The device the slave is, with serial number `serial`: from its ESI file (each file
    /// parsed once, in `esi_files`), else a built-in one.
    fn device(
        &self,
        serial: u32,
        at: &SlaveAt<'_>,
        esi_files: &mut EsiFiles,
    ) -> Result<DeviceInfo, ConfigError> {
        Ok(match &self.esi {
            Some(esi) => esi_files.device(
                at.src,
                esi,
                self.device.as_deref(),
                serial,
                (at.field("esi"), at.key_line("esi")),
                (at.field("device"), at.key_line("device")),
            )?,
            // A junction is a coupler unless the file says otherwise: an ET1100 with four MII
            // ports branches the line, it drives no motor. A real device's model is that device.
            None => match self
                .device
                .as_deref()
                .unwrap_or(default_device(&self.model))
            {
                "servo-drive" => DeviceInfo::servo_drive(serial),
                "coupler" => DeviceInfo::coupler(&self.name, serial),
                "oversampling-terminal" => {
                    DeviceInfo::oversampling_terminal(serial, self.samples(at)?)
                }
                other => match CATALOG.iter().find(|c| c.0 == other) {
                    Some(c) => c.2(serial),
                    None => {
                        return Err(at.error(
                            at.line,
                            "device",
                            format!("unknown device \"{other}\""),
                            "use servo-drive, coupler, oversampling-terminal, ek1100, el2828 or el2889, or describe the device with esi = \"file.xml\"",
                        ));
                    }
                },
            },
        })
    }

    /// The identity the file gives (vendor, product, revision, SII name) over the device's.
    fn override_identity(
        &self,
        device: &mut DeviceInfo,
        at: &SlaveAt<'_>,
    ) -> Result<(), ConfigError> {
        if let Some(v) = self.vendor_id {
            device.vendor_id = v;
        }
        if let Some(v) = self.product_code {
            device.product_code = v;
        }
        if let Some(v) = self.revision {
            device.revision = v;
        }
        if let Some(n) = &self.device_name {
            // ethercrab refuses longer strings; the SII's string length is one byte.
            if n.len() > 64 {
                return Err(at.error(
                    at.key_line("device_name"),
                    "device_name",
                    format!("{} bytes, more than an SII name may have", n.len()),
                    "give a name of at most 64 bytes",
                ));
            }
            device.name = n.clone();
        }
        Ok(())
    }

    /// The delays the file gives over the model's, each checked.
    fn override_delays(&self, model: &mut EscModel, at: &SlaveAt<'_>) -> Result<(), ConfigError> {
        for (name, v, target) in [
            (
                "forwarding_delay_ns",
                self.forwarding_delay_ns,
                &mut model.forwarding_delay_ns,
            ),
            (
                "processing_delay_ns",
                self.processing_delay_ns,
                &mut model.processing_delay_ns,
            ),
            (
                "link_phy_delay_ns",
                self.link_phy_delay_ns,
                &mut model.link_phy_delay_ns,
            ),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && (0.0..=1e6).contains(&v)) {
                    return Err(at.error(
                        at.line,
                        name,
                        format!("{v} is not a delay"),
                        "give a delay between 0 and 1000000 ns",
                    ));
                }
                *target = v;
            }
        }
        Ok(())
    }

    /// The cable length, the crystal's error and its wander are in range.
    /// The ring cable (`ring_port`, `ring_cable_m`), checked against the model's ports.
    fn ring_cable(
        &self,
        model: &EscModel,
        at: &SlaveAt<'_>,
    ) -> Result<Option<crate::segment::RingCable>, ConfigError> {
        let Some(port) = self.ring_port else {
            return Ok(None);
        };
        if !port_ok(model, port) || port == self.entry_port {
            return Err(at.error(
                at.key_line("ring_port"),
                "ring_port",
                format!("port {port} cannot take the ring cable"),
                "name a free port of the slave's model (a line's last slave: 1)",
            ));
        }
        if !(self.ring_cable_m.is_finite() && (0.0..=100_000.0).contains(&self.ring_cable_m)) {
            return Err(at.error(
                at.key_line("ring_cable_m"),
                "ring_cable_m",
                format!("{} m is not a cable length", self.ring_cable_m),
                "give a length between 0 and 100000 m",
            ));
        }
        Ok(Some(crate::segment::RingCable {
            port,
            cable_m: self.ring_cable_m,
        }))
    }

    /// An `oversampling-terminal`'s samples per cycle (`oversampling`, 4 when absent).
    fn samples(&self, at: &SlaveAt<'_>) -> Result<u8, ConfigError> {
        match self.oversampling {
            None => Ok(4),
            Some(n @ 1..=100) => Ok(n as u8),
            Some(n) => Err(at.error(
                at.key_line("oversampling"),
                "oversampling",
                format!("{n} samples per cycle"),
                "give the terminal's samples per cycle, 1 to 100 (its SYNC0 runs that many times a cycle)",
            )),
        }
    }

    /// `oversampling` belongs to an oversampling terminal only.
    fn check_oversampling(&self, device: &DeviceInfo, at: &SlaveAt<'_>) -> Result<(), ConfigError> {
        if self.oversampling.is_some() && device.oversampling == 0 {
            return Err(at.error(
                at.key_line("oversampling"),
                "oversampling",
                "the device does not oversample".to_string(),
                "set device = \"oversampling-terminal\", or leave oversampling out",
            ));
        }
        Ok(())
    }

    /// `pll_limit_us` in ns (0: none).
    fn pll_limit_ns(&self, at: &SlaveAt<'_>) -> Result<u32, ConfigError> {
        let Some(us) = self.pll_limit_us else {
            return Ok(0);
        };
        if !(us.is_finite() && us > 0.0 && us <= 1_000_000.0) {
            return Err(at.error(
                at.key_line("pll_limit_us"),
                "pll_limit_us",
                format!("{us} us is not a PLL limit"),
                "give the |0x092C| in us past which the drive's PLL loses lock (above 0, at most 1000000), or leave it out for none",
            ));
        }
        Ok((us * 1000.0).round().max(1.0) as u32)
    }

    fn check_cable_and_crystal(&self, at: &SlaveAt<'_>) -> Result<(), ConfigError> {
        if !(self.cable_m.is_finite() && (0.0..=100_000.0).contains(&self.cable_m)) {
            return Err(at.error(
                at.line,
                "cable_m",
                format!("{} m is not a cable length", self.cable_m),
                "give a length between 0 and 100000 m",
            ));
        }
        if !(self.ppm.is_finite() && self.ppm.abs() <= 1000.0) {
            return Err(at.error(
                at.line,
                "ppm",
                format!("{} ppm is not a crystal error", self.ppm),
                "give a value between -1000 and 1000",
            ));
        }
        if !(self.wander_ppm_per_sqrt_s.is_finite()
            && (0.0..=10.0).contains(&self.wander_ppm_per_sqrt_s))
        {
            return Err(at.error(
                at.line,
                "wander_ppm_per_sqrt_s",
                format!("{} is not a wander", self.wander_ppm_per_sqrt_s),
                "give a value between 0 and 10",
            ));
        }
        Ok(())
    }

    /// Where the slave connects, its own entry port checked on `model`: the master, or a port
    /// of a slave listed before it (`names`, `specs`).
    fn upstream(
        &self,
        model: &EscModel,
        names: &[&str],
        specs: &[SlaveSpec],
        at: &SlaveAt<'_>,
    ) -> Result<Upstream, ConfigError> {
        if !port_ok(model, self.entry_port) {
            return Err(at.error(
                at.line,
                "entry_port",
                format!("port {} does not exist on {}", self.entry_port, self.model),
                "use a port the model has (servo-mii: 0, 1)",
            ));
        }
        if self.upstream == "master" {
            return Ok(Upstream::Master);
        }
        let Some(k) = names.iter().position(|n| *n == self.upstream) else {
            return Err(at.error(
                at.line,
                "upstream",
                format!(
                    "no slave named \"{}\" is listed before this one",
                    self.upstream
                ),
                "name a slave listed earlier, or \"master\"",
            ));
        };
        let up: &SlaveSpec = &specs[k];
        if !port_ok(&up.model, self.upstream_port) {
            return Err(at.error(
                at.line,
                "upstream_port",
                format!(
                    "port {} does not exist on \"{}\"",
                    self.upstream_port, self.upstream
                ),
                "use a port of the upstream slave's model",
            ));
        }
        Ok(Upstream::Slave {
            index: k,
            port: self.upstream_port,
        })
    }
}

/// The ESI files a segment's slaves name, each parsed once, and the devices built from them,
/// each built once (the slaves that are one device share its dictionary).
#[derive(Default)]
struct EsiFiles {
    files: HashMap<PathBuf, Arc<crate::esi::EsiFile>>,
    devices: HashMap<(PathBuf, String), DeviceInfo>,
}

impl EsiFiles {
    /// The device `device` (a `<Type>` name; `None`: the file's only one) of the ESI file `esi`
    /// (relative to the folder of the configuration file `src`) with serial number `serial`.
    /// `esi_at` and `device_at` are the fields and lines errors name.
    fn device(
        &mut self,
        src: &ConfigSource<'_>,
        esi: &str,
        device: Option<&str>,
        serial: u32,
        esi_at: (String, Option<usize>),
        device_at: (String, Option<usize>),
    ) -> Result<DeviceInfo, ConfigError> {
        let path = Path::new(src.file)
            .parent()
            .unwrap_or(Path::new(""))
            .join(esi);
        let file = match self.files.get(&path) {
            Some(f) => Arc::clone(f),
            None => {
                let f = crate::esi::load(&path).map_err(|e| {
                    let (field, line) = esi_at.clone();
                    if e.kind == crate::esi::EsiErrorKind::Io {
                        src.at(
                            line,
                            field,
                            format!("{}: {}", path.display(), e.message),
                            "give the path of an ESI file, relative to the folder of this file",
                        )
                    } else {
                        src.at(
                            line,
                            field,
                            format!("the ESI file is not usable: {e}"),
                            "correct the ESI file at that line, or use another one",
                        )
                    }
                })?;
                let f = Arc::new(f);
                self.files.insert(path.clone(), Arc::clone(&f));
                f
            }
        };
        let names = file
            .device_names()
            .iter()
            .map(|n| format!("\"{n}\""))
            .collect::<Vec<_>>()
            .join(", ");
        let chosen = match device {
            Some(name) => file.device(name).ok_or_else(|| {
                src.at(
                    device_at.1,
                    device_at.0.clone(),
                    format!("{} has no device \"{name}\"", path.display()),
                    format!("use one of its devices' <Type> names: {names}"),
                )
            })?,
            None if file.devices.len() == 1 => &file.devices[0],
            None => {
                return Err(src.at(
                    esi_at.1,
                    device_at.0,
                    format!(
                        "{} describes {} devices",
                        path.display(),
                        file.devices.len()
                    ),
                    format!("say which with device = one of {names}"),
                ));
            }
        };
        let template = self
            .devices
            .entry((path, chosen.type_name.clone()))
            .or_insert_with(|| chosen.device_info(serial));
        Ok(DeviceInfo {
            serial,
            ..template.clone()
        })
    }
}

/// A file holding only a segment (`ecsync bringup --config`).
#[derive(Debug, Clone, Deserialize)]
pub struct SegmentFile {
    /// The segment.
    pub segment: SegmentConfig,
}

/// Parses a file's segment. Other top-level tables (host, run, ...) are left to their owners.
pub fn parse_segment(file: &str, text: &str) -> Result<Vec<SlaveSpec>, ConfigError> {
    let f: SegmentFile = ConfigSource::new(file, text).deserialize()?;
    f.segment.to_specs(file, text, "segment")
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
[segment]
seed = 7
[[segment.slave]]
name = "a"
upstream = "master"
[[segment.slave]]
name = "b"
upstream = "a"
upstream_port = 1
ppm = -3.5
"#;

    #[test]
    fn parses_a_line() {
        let specs = parse_segment("net.toml", GOOD).unwrap();
        assert_eq!(specs.len(), 2);
        assert_eq!(specs[1].upstream, Upstream::Slave { index: 0, port: 1 });
        assert_eq!(specs[1].crystal.ppm, -3.5);
    }

    /// A real ESC's registers as the captures read them find their device family: the EK1100
    /// (type 0x11, 0x0008 = 0x00FC, 0x0007 = 0x3B, soem-sdinfo-ek1100-el1004.pcapng) the
    /// et1100-coupler, the LAN9252 (0xC0, 0x01CC, 0x1F, soem-single-lan9252.pcapng) the
    /// lan9252, the EL1004 (0x12, 0x01FC, 0x4A) an ET1200 terminal; the AKD (0x04, 0x0184,
    /// 0x0F) the calibrated servo-mii-dc32 first, which has the same registers.
    #[test]
    fn real_registers_find_their_family() {
        assert_eq!(
            model_for_registers(0x11, 0x00fc, 0x3b),
            ("et1100-coupler", ModelMatch::Exact)
        );
        assert_eq!(
            model_for_registers(0xc0, 0x01cc, 0x1f),
            ("lan9252", ModelMatch::Exact)
        );
        assert_eq!(
            model_for_registers(0x12, 0x01fc, 0x4a),
            ("et1200-terminal", ModelMatch::Exact)
        );
        assert_eq!(
            model_for_registers(0x04, 0x0184, 0x0f),
            ("servo-mii-dc32", ModelMatch::Exact)
        );
        for name in MODEL_NAMES {
            assert!(model_named(name).is_some(), "{name}");
        }
    }

    #[test]
    fn every_model_name_builds_its_model() {
        for (name, model) in [
            ("servo-mii", EscModel::servo_mii()),
            ("servo-mii-dc32", EscModel::servo_mii_dc32()),
            ("ebus-terminal", EscModel::ebus_terminal(DcSupport::Full64)),
            (
                "ebus-terminal-no-dc",
                EscModel::ebus_terminal(DcSupport::None),
            ),
            ("junction-mii", EscModel::junction_mii()),
            ("et1100-coupler", EscModel::et1100_coupler()),
            (
                "et1200-terminal",
                EscModel::et1200_terminal(DcSupport::Full64),
            ),
            (
                "et1200-terminal-receive-times",
                EscModel::et1200_terminal(DcSupport::ReceiveTimes),
            ),
            ("lan9252", EscModel::lan9252()),
            ("akd", EscModel::akd_drive()),
        ] {
            let text = GOOD.replace("name = \"b\"", &format!("name = \"b\"\nmodel = \"{name}\""));
            let specs = parse_segment("net.toml", &text).unwrap();
            assert_eq!(specs[1].model, model, "{name}");
        }
        let specs = parse_segment(
            "net.toml",
            &GOOD.replace("name = \"b\"", "name = \"b\"\nmodel = \"servo-mii-dc32\""),
        )
        .unwrap();
        assert_eq!(specs[1].model.dc, DcSupport::Full32);
        assert_eq!(specs[1].model.features(), 0x0184);
        let e = parse_segment(
            "net.toml",
            &GOOD.replace("name = \"b\"", "name = \"b\"\nmodel = \"et9999\""),
        )
        .unwrap_err();
        assert_eq!(e.field, "segment.slave[1].model");
        assert!(e.message.contains("et9999"), "{e}");
        // The fix names every model, the families too.
        for name in MODEL_NAMES {
            assert!(e.fix.contains(name), "{name}: {e}");
        }
    }

    /// Where `locate` puts a problem: the key's line, the header of the table the key names,
    /// the key of an inline table in its parent, the table's header, or nowhere.
    #[test]
    fn problems_are_located_by_key_table_or_parent() {
        let text = "[run]\ncycle_us = 5\n\n[host]\njs = { sigma_ns = 1e9 }\n\n[[bridge.port.window]]\nopen_ns = 0\n\n[methods.median]\n";
        let src = ConfigSource::new("s.toml", text);
        let at = |table: &str, key: &str| src.error(table, key, "m", "f").line;
        assert_eq!(at("run", "cycle_us"), Some(2));
        assert_eq!(
            at("host.js", "sigma_ns"),
            Some(5),
            "inline: the parent's key"
        );
        assert_eq!(
            at("bridge.port", "window"),
            Some(7),
            "an array of tables' header"
        );
        assert_eq!(
            at("methods.median", "window"),
            Some(10),
            "the table's header"
        );
        assert_eq!(at("methods", "median"), Some(10), "the table the key names");
        assert_eq!(at("segment", "slave"), None);
        let e = src.error("run", "cycle_us", "5 us", "give 1000");
        assert_eq!(
            e.to_string(),
            "s.toml:2: run.cycle_us: 5 us; fix: give 1000"
        );
    }

    #[test]
    fn errors_name_file_line_field_and_fix() {
        let bad = GOOD.replace("ppm = -3.5", "ppmm = -3.5");
        let e = parse_segment("net.toml", &bad).unwrap_err();
        assert_eq!(e.line, Some(11));
        assert!(e.to_string().starts_with("net.toml:11: ppmm"), "{e}");
        assert!(e.message.contains("unknown field"), "{e}");

        let bad = GOOD.replace("upstream = \"a\"", "upstream = \"zz\"");
        let e = parse_segment("net.toml", &bad).unwrap_err();
        assert_eq!(e.field, "segment.slave[1].upstream");
        assert_eq!(e.line, Some(7));
        assert!(e.fix.contains("master"));

        let bad = GOOD.replace("ppm = -3.5", "cable_m = -1.0");
        let e = parse_segment("net.toml", &bad).unwrap_err();
        assert_eq!(e.field, "segment.slave[1].cable_m");

        let bad = GOOD.replace("upstream_port = 1", "upstream_port = 2");
        let e = parse_segment("net.toml", &bad).unwrap_err();
        assert_eq!(e.field, "segment.slave[1].upstream_port");

        // The drive's PLL limit: a positive time, carried to the device; refused otherwise.
        let good = GOOD.replace("ppm = -3.5", "ppm = -3.5\npll_limit_us = 2.5");
        let specs = parse_segment("net.toml", &good).unwrap();
        assert_eq!(specs[1].device.pll_limit_ns, 2_500);
        assert_eq!(specs[0].device.pll_limit_ns, 0);
        let bad = GOOD.replace("ppm = -3.5", "ppm = -3.5\npll_limit_us = -1");
        let e = parse_segment("net.toml", &bad).unwrap_err();
        assert_eq!(e.field, "segment.slave[1].pll_limit_us");
        assert_eq!(e.line, Some(12));
        assert!(e.fix.contains("PLL"), "{e}");
    }
}
