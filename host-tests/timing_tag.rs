//! The time tag (`odo_unit::timing::tag`): which PPS edge a time message names
//! (`time_tag_pps` previous/next), the measured second of an HSI timer, and the GNSS second
//! of each label through the discipline's holdover.

use odo_unit::timing::*;

mod support;
use support::pps_sim::*;

#[test]
fn time_tag_measures_the_second_on_an_hsi_timer() {
    // Timer 4 % slow: one true second is 0.96 nominal seconds of ticks. Edge 7 at t = 7 s,
    // edge 8 lost, a message of second 8 arriving 1.01 s after edge 7 (0.11 s after the
    // lost edge). With the nominal second as the window it would be tied to edge 7.
    let p = u64::from(HZ) * 96 / 100;
    let mut tag = TimeTagger::new(TimeTagPps::Previous, u64::from(HZ));
    assert_eq!(tag.second_ticks(), u64::from(HZ));
    tag.on_edge(6 * p, 6);
    tag.on_edge(7 * p, 7);
    assert_eq!(tag.second_ticks(), p);
    assert!(!tag.on_message(1_000_008, 7 * p + p * 101 / 100));
    assert_eq!(tag.gps_second(7), None);
    assert!(tag.on_message(1_000_007, 7 * p + p * 99 / 100));
    assert_eq!(tag.gps_second(9), Some(1_000_009));
    // A gap of labels (edges lost) is averaged; the measurement survives invalidation.
    tag.on_edge(10 * p + 3, 10);
    assert_eq!(tag.second_ticks(), p + 1);
    tag.invalidate();
    assert_eq!(tag.second_ticks(), p + 1);
    // Timer 4 % fast: a message 0.98 s after its edge (1.0192 nominal seconds) is tied.
    let p = u64::from(HZ) * 104 / 100;
    let mut tag = TimeTagger::new(TimeTagPps::Previous, u64::from(HZ));
    tag.on_edge(p, 1);
    tag.on_edge(2 * p, 2);
    assert!(tag.on_message(500, 2 * p + p * 98 / 100));
    assert_eq!(tag.gps_second(2), Some(500));
}

#[test]
fn time_tag_previous_and_next() {
    let p = u64::from(HZ);
    // Previous: the message after edge 7 names it.
    let mut tag = TimeTagger::new(TimeTagPps::Previous, p);
    tag.on_edge(7 * p, 7);
    assert!(tag.on_message(1_000_000, 7 * p + p / 10));
    assert_eq!(tag.gps_second(7), Some(1_000_000));
    assert_eq!(tag.gps_second(9), Some(1_000_002));
    assert_eq!(tag.gps_second(6), Some(999_999));
    assert_eq!(tag.gps_time(7), Some(GpsTime::from_seconds(1_000_000)));
    // A message more than a second after the last edge is not associated.
    assert!(!tag.on_message(1_000_005, 8 * p + 1));
    assert_eq!(tag.gps_second(7), Some(1_000_000));
    // A disagreeing message replaces the mapping and is counted.
    tag.on_edge(8 * p, 8);
    assert!(tag.on_message(2_000_000, 8 * p + 5));
    assert_eq!(tag.mismatches(), 1);
    assert_eq!(tag.gps_second(8), Some(2_000_000));

    // Next: the message before edge 7 announces it.
    let mut tag = TimeTagger::new(TimeTagPps::Next, p);
    tag.on_edge(6 * p, 6);
    assert!(tag.on_message(1_000_000, 6 * p + p / 2));
    assert_eq!(tag.gps_second(6), None);
    tag.on_edge(7 * p, 7);
    assert_eq!(tag.gps_second(7), Some(1_000_000));
    // A message more than a second before its edge is dropped.
    tag.on_message(5, 8 * p - p - 1);
    tag.on_edge(8 * p, 8);
    assert_eq!(tag.gps_second(8), Some(1_000_001));
    tag.invalidate();
    assert_eq!(tag.gps_second(8), None);
}

#[test]
fn time_tag_follows_the_discipline_through_holdover() {
    // Labels from the discipline count seconds in holdover, so the mapping survives it.
    let mut sc = Scenario::new(30.0, 5, 30);
    sc.lost = vec![10, 11, 12];
    let mut disc = pps_disc();
    let r = run(&mut disc, &sc.edges(), sc.crystal, sc.seconds);
    let mut tag = TimeTagger::new(TimeTagPps::Previous, u64::from(HZ));
    let gps0 = 1_400_000_000u32;
    let mut checked = 0;
    for (edge, event) in &r.events {
        if let PpsEvent::Locked { second }
        | PpsEvent::Accepted { second, .. }
        | PpsEvent::Reacquired { second, .. } = event
        {
            tag.on_edge(edge.tick, *second);
            let truth = edge.second.expect("real edge");
            if truth < 5 {
                tag.on_message(gps0 + truth, edge.tick + 1000);
            }
            assert_eq!(tag.gps_second(*second), Some(gps0 + truth));
            checked += 1;
        }
    }
    assert!(checked > 20);
    assert_eq!(tag.mismatches(), 0);
}
