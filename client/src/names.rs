//! Words for the API's enums and parameter vectors, as the CLI prints them.

use glissade_core::point::DesignPoint;
use std::collections::BTreeMap;

use glissade_proto::v1;

pub fn study_state_name(state: i32) -> &'static str {
    match v1::StudyState::try_from(state) {
        Ok(v1::StudyState::Active) => "active",
        Ok(v1::StudyState::Done) => "done",
        Ok(v1::StudyState::Failed) => "failed",
        Ok(v1::StudyState::Cancelled) => "cancelled",
        _ => "unknown",
    }
}

pub fn point_state_name(state: i32) -> &'static str {
    match v1::PointState::try_from(state) {
        Ok(v1::PointState::Pending) => "pending",
        Ok(v1::PointState::Leased) => "leased",
        Ok(v1::PointState::Done) => "done",
        Ok(v1::PointState::Failed) => "failed",
        Ok(v1::PointState::Cancelled) => "cancelled",
        _ => "unknown",
    }
}

pub fn strategy_name(strategy: i32) -> &'static str {
    match v1::InitStrategy::try_from(strategy) {
        Ok(v1::InitStrategy::Cold) => "cold",
        Ok(v1::InitStrategy::Previous) => "previous",
        Ok(v1::InitStrategy::Nearest) => "nearest",
        Ok(v1::InitStrategy::Blend) => "blend",
        Ok(v1::InitStrategy::Linear) => "linear",
        _ => "unknown",
    }
}

pub fn order_name(order: i32) -> &'static str {
    match v1::PointOrder::try_from(order) {
        Ok(v1::PointOrder::Ascending) => "asc",
        Ok(v1::PointOrder::Descending) => "desc",
        Ok(v1::PointOrder::Greedy) => "greedy",
        _ => "unknown",
    }
}

/// `f1=0.1 f2=0.15`, in name order: the study library's `DesignPoint` display (a map that is no
/// design point as it came).
pub fn describe_parameters(parameters: &BTreeMap<String, f64>) -> String {
    DesignPoint::try_from(parameters.clone()).map_or_else(|_| format!("{parameters:?}"), |p| p.to_string())
}
