//! The one JSON of glissade's messages: proto3's JSON mapping of `glissade.v1`, generated from
//! the .proto by pbjson-build (build.rs). The web API (`/api/studies...`) and the CLI's `--json`
//! write a study with these, so a study reads the same wherever it is read, and as GetStudy
//! returns it.
//!
//! How it reads: fields by their .proto names (snake_case); every field of a message written,
//! default values too, except an absent message or `optional` field; enums by their value's name
//! (`"STUDY_STATE_DONE"`); 64-bit integers (ids, iterations, Unix milliseconds) as strings
//! (`"study_id": "3"`), as the mapping has them, since JavaScript's numbers stop at 2^53.
//! Reading takes numbers or strings for them, and takes an enum's name or number.

use serde::Serialize;

use crate::v1;

/// A message's JSON value.
pub fn to_value<M: Serialize>(message: &M) -> serde_json::Value {
    // (pbjson writes strings, numbers, booleans, arrays and maps keyed by strings: nothing that
    // JSON cannot hold)
    serde_json::to_value(message).expect("a message's JSON")
}

/// A message's JSON text, written straight from the message (a large study's is megabytes).
pub fn to_vec<M: Serialize>(message: &M) -> Vec<u8> {
    serde_json::to_vec(message).expect("a message's JSON")
}

/// A message's JSON text, as [`to_vec`] writes it.
pub fn to_string<M: Serialize>(message: &M) -> String {
    serde_json::to_string(message).expect("a message's JSON")
}

/// A study's JSON: what `/api/studies/ID` serves and `glissade show ID --json` prints.
pub fn study(study: &v1::Study) -> serde_json::Value {
    to_value(study)
}

/// A list of studies' JSON, an array: what `/api/studies` serves and `glissade studies --json`
/// prints.
pub fn studies(studies: &[v1::Study]) -> serde_json::Value {
    to_value(&studies)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn study() -> v1::Study {
        let point = v1::PointStatus {
            study_id: 7,
            point_id: 2,
            parameters: [("f1".to_owned(), 0.15)].into(),
            state: v1::PointState::Done.into(),
            iterations: 41,
            error_indicator: Some(8.5e-5),
            qoi: [("slip_A".to_owned(), 1.25e-6)].into(),
            started_from: Some(v1::SolutionRef {
                scene_hash: "ab".repeat(32),
                parameters: [("f1".to_owned(), 0.1)].into(),
                study_id: 7,
                point_id: 1,
            }),
            eta_history: vec![0.5, 1e-2, 8.5e-5],
            contact: vec![v1::ContactActivity {
                interface: "floor".into(),
                friction: 0.3,
                contact_nodes: 5,
                first_slip_time: Some(4.2e-5),
                landings_while_sliding: 24,
                chatters: true,
                ..Default::default()
            }],
            ..Default::default()
        };
        let ladder = v1::LadderError { finals: vec![1.0, 1.1], estimate: 0.03, order: None, ..Default::default() };
        v1::Study {
            study_id: 7,
            label: "sweep, 応力".into(),
            state: v1::StudyState::Done.into(),
            strategy: v1::InitStrategy::Linear.into(),
            tolerance: 1e-4,
            progress: Some(v1::StudyProgress { total: 1, done: 1, iterations: 41, ..Default::default() }),
            parameters: vec!["f1".into()],
            created_unix_ms: 1_790_000_000_123,
            points: vec![point],
            units: [("slip_A".to_owned(), "m".to_owned())].into(),
            to_accuracy: Some(v1::StudyToAccuracy {
                accuracy: 0.05,
                confirmed: Some(true),
                pilots: vec![v1::PilotLadders {
                    point_id: 2,
                    asked: vec![v1::LevelAsked { refinement: "time".into(), time_factor: 2, mesh_factor: 1 }],
                    report: Some(v1::AccuracyReport {
                        qoi: vec![v1::QoiLadders {
                            name: "slip_A".into(),
                            time: Some(ladder.clone()),
                            joint: Some(v1::LadderError { order: Some(1.9), ..ladder }),
                            ..Default::default()
                        }],
                        ..Default::default()
                    }),
                }],
                ..Default::default()
            }),
            verdicts: vec!["slip_A: the time step's error dominates".into()],
            ..Default::default()
        }
    }

    /// A study goes out as JSON and comes back the same message, every field of it.
    #[test]
    fn a_study_round_trips_through_its_json() {
        let s = study();
        let text = to_vec(&s);
        let back: v1::Study = serde_json::from_slice(&text).expect("its own JSON reads back");
        assert_eq!(back, s);
        // and a list of them
        let list = studies(&[s.clone(), v1::Study::default()]);
        let back: Vec<v1::Study> = serde_json::from_value(list).expect("a list reads back");
        assert_eq!(back, vec![s, v1::Study::default()]);
    }

    /// What a reader sees: the .proto's names, every field (defaults too), enums by name, 64-bit
    /// integers as strings; an absent message or optional field is left out.
    #[test]
    fn a_studys_json_reads_as_proto3s_mapping() {
        let json = super::study(&study());
        assert_eq!(json["study_id"], "7");
        assert_eq!(json["created_unix_ms"], "1790000000123");
        assert_eq!(json["state"], "STUDY_STATE_DONE");
        assert_eq!(json["order"], "POINT_ORDER_UNSPECIFIED");
        assert_eq!(json["max_iterations"], 0, "a default is written");
        assert_eq!(json["label"], "sweep, 応力");
        assert_eq!(json["progress"]["done"], 1);
        assert_eq!(json["progress"]["iterations"], "41");
        assert_eq!(json["units"]["slip_A"], "m");
        assert!(json.get("accuracy").is_none(), "an absent message is left out: {json}");
        let point = &json["points"][0];
        assert_eq!((&point["point_id"], &point["state"]), (&"2".into(), &"POINT_STATE_DONE".into()));
        assert_eq!(point["parameters"]["f1"], 0.15);
        assert_eq!(point["eta_history"][2], 8.5e-5);
        assert_eq!(point["started_from"]["point_id"], "1");
        assert_eq!(point["contact"][0]["chatters"], true);
        assert_eq!(point["contact"][0]["first_slip_time"], 4.2e-5);
        assert_eq!(point["error_indicator"], 8.5e-5);
        // a point without an error indicator (failed before its first iteration, or leased and
        // not yet reported) has none in its JSON, where it once read 1.797e308
        let failed = v1::PointStatus { state: v1::PointState::Failed.into(), ..Default::default() };
        assert!(to_value(&failed).get("error_indicator").is_none(), "{}", to_value(&failed));
        let t = &json["to_accuracy"];
        assert_eq!(t["confirmed"], true);
        let q = &t["pilots"][0]["report"]["qoi"][0];
        assert!(q["time"].get("order").is_none() && q["joint"]["order"] == 1.9, "{q}");
        // a reader may give the integers as numbers, and an enum by its number
        let mut given = json.clone();
        given["study_id"] = 7.into();
        given["state"] = (v1::StudyState::Done as i32).into();
        assert_eq!(serde_json::from_value::<v1::Study>(given).expect("numbers read"), study());
    }
}
