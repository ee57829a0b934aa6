//! A network's crystals against what the DC units' time control loops can follow.

use super::source::ConfigSource;
use super::{ConfigError, SegmentConfig, line_of};
use crate::segment::SlaveSpec;

impl SegmentConfig {
    /// Every DC slave's crystal within what its time control loop follows of the reference
    /// (the first DC slave from the master, as masters take it): past that range its clock
    /// never locks and the bring-up fails after its timeout with no name to the cause.
    pub(super) fn check_crystals_lockable(
        &self,
        src: &ConfigSource<'_>,
        path: &str,
        seg: &crate::Segment,
        specs: &[SlaveSpec],
    ) -> Result<(), ConfigError> {
        let max_ppm = crate::dc_unit::max_following_ppm();
        let dc: Vec<usize> = (0..seg.len())
            .filter(|&p| seg.esc(p).dc().is_some())
            .map(|p| seg.spec_index(p))
            .collect();
        let Some(&r) = dc.first() else {
            return Ok(());
        };
        let ref_ppm = specs[r].crystal.ppm;
        for &i in &dc[1..] {
            let d = specs[i].crystal.ppm - ref_ppm;
            if d.abs() > max_ppm {
                let sp = &self.slave[i];
                let span = sp.span();
                let at = src.text[span.clone()]
                    .find("ppm")
                    .map_or(span.start, |o| span.start + o);
                return Err(src.at(
                    Some(line_of(src.text, at)),
                    format!("{path}.slave[{i}].ppm"),
                    format!(
                        "{}'s crystal ({:+.1} ppm) is {:+.1} ppm from the reference {}'s ({:+.1} ppm): its time control loop follows at most {:.0} ppm (Speed Counter Start 0x1000, ESC datasheet section II, 0x0930/0x0932), so its clock would never lock",
                        sp.get_ref().name,
                        specs[i].crystal.ppm,
                        d,
                        self.slave[r].get_ref().name,
                        ref_ppm,
                        max_ppm
                    ),
                    format!(
                        "give a crystal error within {:.0} ppm of the reference's (real crystals are within +-100 ppm)",
                        max_ppm
                    ),
                ));
            }
        }
        Ok(())
    }
}
