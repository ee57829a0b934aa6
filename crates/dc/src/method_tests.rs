//! Tests of `method.rs`.

use super::*;

#[test]
fn every_built_method_names_its_kind() {
    let ctx = MethodContext {
        cycle_ns: 1_000_000,
        target_phase_ns: 250_000,
    };
    let p = MethodParams::default();
    for kind in MethodKind::ALL {
        let m = p.build(kind, &ctx);
        assert_eq!(m.kind(), kind);
        assert_eq!(m.name(), kind.name());
        assert_eq!(m.init_cycles(), p.init_frames(kind));
        assert_eq!(kind.has_init_frames(), p.init_frames(kind) > 0);
        // The kind's word agrees with the built method's own.
        assert_eq!(kind.is_master_shift(), m.is_master_shift(), "{kind}");
    }
    // The aimed methods take the target: snap as ethercrab's shift into the cycle.
    assert_eq!(
        p.build(
            MethodKind::Snap,
            &MethodContext {
                target_phase_ns: -250_000,
                ..ctx
            }
        ),
        Method::Snap(Snap { shift_ns: 750_000 })
    );
    assert_eq!(
        p.build(MethodKind::SoemPi, &ctx),
        Method::SoemPi(SoemPi::new(250_000))
    );
}

#[test]
fn the_dcm_settings_default_to_the_controllers_defaults() {
    let d = DcmSettings::default().to_params(0, 1_000_000, false);
    assert_eq!(d, DcmParams::default_for(0, 1_000_000));
    let d = DcmSettings::default().to_params(7, 1_000_000, true);
    assert_eq!(d, DcmParams::default_bus_shift(7, 1_000_000));
    // The hold is a time: at 500 us it is twice the cycles.
    let d = DcmSettings::default().to_params(0, 500_000, false);
    assert_eq!(d.in_sync_hold_cycles, 3_000);
}

#[test]
fn rounding_is_half_away_from_zero_as_std_rounds() {
    // f64::round's results, by hand (it is not in core).
    for (x, r) in [
        (0.0, 0),
        (0.5, 1),
        (-0.5, -1),
        (1.5, 2),
        (2.5, 3),
        (-2.5, -3),
        // The largest float below 0.5: adding 0.5 would round up to 1.
        (0.499_999_999_999_999_94, 0),
        (12_345.678_9, 12_346),
        (-7.2, -7),
        (4.5e15, 4_500_000_000_000_000),
        (1e300, i64::MAX),
        (-1e300, i64::MIN),
        (f64::NAN, 0),
    ] {
        assert_eq!(round_to_i64(x), r, "{x}");
    }
}

#[test]
fn refused_values_name_the_table_key_and_fix() {
    let mut p = MethodParams::default();
    p.median_fit.window = 10;
    let e = p.check().unwrap_err();
    assert_eq!(e.table, ParamTable::Method(MethodKind::MedianFit));
    assert_eq!(e.key, "window");
    let mut s = std::string::String::new();
    core::fmt::write(&mut s, format_args!("{e}")).unwrap();
    assert_eq!(
        s,
        "methods.median-fit.window: window w = 10 must be odd and between 1 and 63; fix: use an odd width such as 11 (the letter's), so the median is one of the samples"
    );
    let ctx = MethodContext {
        cycle_ns: 40_000,
        target_phase_ns: 0,
    };
    // DCM's default validity gate (50 us) does not fit a 40 us cycle: refused where DCM
    // runs only.
    let p = MethodParams::default();
    assert!(p.check_use(MethodKind::Median, &ctx).is_ok());
    let e = p.check_use(MethodKind::DcmBusShift, &ctx).unwrap_err();
    assert_eq!(e.key, "max_valid_us");
    let e = MethodContext {
        cycle_ns: 1_000_000,
        target_phase_ns: 500_000,
    }
    .check()
    .unwrap_err();
    assert_eq!(e.table, ParamTable::Run);
    assert_eq!(e.key, "target_phase_us");
    assert!(MethodContext::target_phase_from_us(f64::NAN).is_err());
    assert_eq!(MethodContext::target_phase_from_us(-12.3456), Ok(-12_346));
}
