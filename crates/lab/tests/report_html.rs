//! report.html shows its plots from the file alone: a short comparison's report, copied into an
//! empty folder without the SVG and PNG files beside it, is rendered by headless Chromium and
//! the screenshot is looked at pixel by pixel.
//!
//! Needs Chromium (`apt-get install chromium`; `ECSYNC_CHROMIUM` names another binary), hence
//! ignored by default; `cargo test -p ecsync-lab --test report_html -- --ignored` runs it, and
//! then a missing Chromium is a failure, not a skip.

use ecsync_lab::report::summarize;
use ecsync_sim::preset::PAPER_2024_TOML;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::AtomicU64;
use std::time::{Duration, Instant};

/// The screenshot's size: the report's width (its body is at most 1200 px) and the height of
/// the verdict, the tables and the first figures.
const WIDTH: u32 = 1400;
const HEIGHT: u32 = 4000;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecsync-html-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The paper network, one run of 20 000 recorded cycles after the 10 s warm-up the methods'
/// init frames need: every output of `ecsync compare`'s plots and report.html in `dir`.
/// Returns the report's order of methods.
fn short_comparison(dir: &Path) -> Vec<String> {
    let mut s = ecsync_lab::parse("paper-2024", PAPER_2024_TOML).unwrap();
    s.runs = 1;
    s.cycles = 20_000;
    s.warmup_cycles = 10_500;
    let c = ecsync_lab::compare(&s, 2, &AtomicU64::new(0)).unwrap();
    let out = summarize(&c);
    let order: Vec<String> = s.entries().iter().map(|e| e.name()).collect();
    ecsync_lab::plots::write_all(&c, &out, &order, dir).unwrap();
    order
}

/// Renders `html` with headless Chromium into `png`; panics when Chromium is missing, fails or
/// takes more than two minutes.
fn screenshot(html: &Path, png: &Path, profile: &Path) {
    let chromium = std::env::var("ECSYNC_CHROMIUM").unwrap_or_else(|_| "chromium".into());
    let mut child = Command::new(&chromium)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars"])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("--screenshot={}", png.display()))
        .arg(format!("--window-size={WIDTH},{HEIGHT}"))
        .arg(format!("file://{}", html.display()))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| {
            panic!("cannot start {chromium} ({e}): install it (apt-get install chromium) or name it in ECSYNC_CHROMIUM")
        });
    let t0 = Instant::now();
    let status = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        if t0.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("{chromium} took more than 120 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(status.success(), "{chromium} failed: {status}");
}

/// The screenshot's pixels, RGB, row by row.
fn decode(png: &Path) -> (u32, u32, Vec<[u8; 3]>) {
    let dec = png::Decoder::new(std::fs::File::open(png).unwrap());
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.bit_depth, png::BitDepth::Eight, "{info:?}");
    let step = match info.color_type {
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        other => panic!("unexpected PNG colour type {other:?}"),
    };
    let px = buf[..info.buffer_size()]
        .chunks_exact(step)
        .map(|p| [p[0], p[1], p[2]])
        .collect();
    (info.width, info.height, px)
}

fn near(a: [u8; 3], b: [u8; 3], tol: i32) -> bool {
    (0..3).all(|k| (i32::from(a[k]) - i32::from(b[k])).abs() <= tol)
}

#[test]
#[ignore = "needs chromium"]
fn report_html_shows_its_plots_from_the_file_alone_in_headless_chromium() {
    let out = tmp("out");
    let order = short_comparison(&out);
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    // The plots are in the file, not behind a link.
    assert!(
        html.matches("<svg").count() >= 9,
        "report.html holds {} inline SVGs",
        html.matches("<svg").count()
    );
    assert!(!html.contains("<img"), "report.html still has an <img>");
    for f in [
        "hist_phase",
        "hist_margin",
        "series_rs_is",
        "fig4_histograms",
    ] {
        assert!(
            !html.contains(&format!("src=\"{f}.svg\"")),
            "{f}.svg is linked, not inline"
        );
        // The files are still written beside it.
        for ext in ["svg", "png"] {
            assert!(out.join(format!("{f}.{ext}")).exists(), "{f}.{ext} missing");
        }
    }

    // report.html alone in an empty folder (Chromium's profile elsewhere).
    let alone = tmp("alone");
    let page = alone.join("report.html");
    std::fs::copy(out.join("report.html"), &page).unwrap();
    let (shot_dir, profile) = (tmp("shot"), tmp("profile"));
    let shot = shot_dir.join("report.png");
    screenshot(&page, &shot, &profile);
    let names: Vec<_> = std::fs::read_dir(&alone)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, ["report.html"], "the folder held only report.html");

    let (w, h, px) = decode(&shot);
    assert_eq!((w, h), (WIDTH, HEIGHT));
    // Every method's colour is on the page (the tables have none of them: only drawn plots
    // do), in hundreds of pixels.
    let mut first_row = h;
    for (i, name) in order.iter().enumerate() {
        let c = ecsync_lab::plots::method_rgb(i);
        let rows: Vec<u32> = (0..px.len())
            .filter(|&k| near(px[k], c, 12))
            .map(|k| k as u32 / w)
            .collect();
        assert!(
            rows.len() >= 200,
            "{name}'s colour {c:?} is on {} pixels of the screenshot",
            rows.len()
        );
        first_row = first_row.min(rows[0]);
    }
    // The first figure (the phase histogram, 1100 x 540 px) starts around the first row in a
    // method's colour: it is drawn, not blank (axes, grid, outlines, legend, ticks).
    let (top, bottom) = (first_row.saturating_sub(40), (first_row + 460).min(h));
    let mut ink = 0u64;
    for y in top..bottom {
        for x in 0..w {
            if !near(px[(y * w + x) as usize], [255, 255, 255], 8) {
                ink += 1;
            }
        }
    }
    let area = u64::from(bottom - top) * 1100;
    assert!(
        ink * 100 >= area * 3,
        "the first figure's rows {top}..{bottom} have {ink} non-white pixels of {area}"
    );
    for dir in [out, alone, shot_dir, profile] {
        let _ = std::fs::remove_dir_all(dir);
    }
}
