//! M1 (no TSN) explored exhaustively: every worst case equals the bound the paper's UPPAAL
//! queries state (the paper verified that each holds; the explorer finds each reached).

use ecsync_tsn::{Model, Pair, analyze};

#[test]
fn m1_worst_cases_are_the_papers_query_bounds() {
    let r = analyze(Model::M1);
    assert_eq!(
        r.delay_max,
        [40, 60],
        "A[] Delay[0] <= 40, A[] Delay[1] <= 60"
    );
    let get = |p: Pair| r.diff.iter().find(|d| d.0 == p).unwrap().1;
    // M1.xml: L0 - L1 <= 30, L1 - L0 <= 20; L0 - L2 <= 30, L2 - L0 <= 30; L1 - L2 <= 30,
    // L2 - L1 <= 40 (L0 master, L1 = S1, L2 = S2).
    let m_s1 = get(Pair::MasterS1);
    assert_eq!((m_s1.max_a_minus_b, m_s1.max_b_minus_a), (30, 20));
    let m_s2 = get(Pair::MasterS2);
    assert_eq!((m_s2.max_a_minus_b, m_s2.max_b_minus_a), (30, 30));
    let s1_s2 = get(Pair::S1S2);
    assert_eq!((s1_s2.max_a_minus_b, s1_s2.max_b_minus_a), (30, 40));
    assert!(r.blocked.is_none(), "no bridge in M1");
    assert!(r.deadlock, "every run ends when the clocks stop");
    // Delays are computed on the 10-unit grain and are never below one hop's share.
    assert!(r.delay_min.iter().all(|&d| d > 0 && d % 10 == 0));
}
