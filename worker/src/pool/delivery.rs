//! What a pool owes the coordinator for a point it leased: a completion (header and solution
//! file) or a failure, built once when the solve ends, sent until it goes through, and kept in a
//! spool directory when the pool must stop before it could (`--spool`, delivered at the next
//! start): a solved point is never thrown away.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use glissade_proto::chunks;
use glissade_proto::v1::{self, complete_point_message};
use prost::Message;
use tonic::Status;

use super::{Pool, Report, solution_meta};
use glissade_core::io::solution_file;

/// A result ready to send.
#[derive(Debug, Clone, PartialEq)]
pub enum Delivery {
    Fail(v1::FailPointRequest),
    Complete { header: v1::CompletePointHeader, bytes: Vec<u8> },
}

impl Delivery {
    /// The message for `report`, from pool `pool_id`: the solution file is written here, once.
    pub fn new(pool_id: &str, report: Report) -> Self {
        let lease = &report.lease;
        let fail = |error: String, eta: Option<f64>, iterations: u64| {
            Delivery::Fail(v1::FailPointRequest {
                pool_id: pool_id.to_owned(),
                lease_id: lease.lease_id,
                study_id: lease.study_id,
                point_id: lease.point_id,
                error,
                error_indicator: eta,
                iterations,
            })
        };
        let (scene, outcome, started_cold) = match &report.outcome {
            Ok((scene, o, started_cold)) => (scene, o, *started_cold),
            Err(e) => return fail(e.clone(), None, 0),
        };
        let s = &outcome.summary;
        let qoi: std::collections::BTreeMap<String, f64> =
            s.qoi.iter().map(|(k, q)| (k.clone(), q.final_value)).collect();
        if !s.error_indicator.is_finite() || qoi.values().any(|v| !v.is_finite()) {
            return fail("the solve diverged: eta or a QoI is not finite".into(), None, s.iterations as u64);
        }
        let meta = solution_meta(&scene.scene, outcome);
        let mut bytes = Vec::new();
        if let Err(e) = solution_file::write_to(&mut bytes, &outcome.solution, &meta) {
            return fail(format!("writing the solution: {e}"), Some(s.error_indicator), s.iterations as u64);
        }
        let header = v1::CompletePointHeader {
            pool_id: pool_id.to_owned(),
            lease_id: lease.lease_id,
            study_id: lease.study_id,
            point_id: lease.point_id,
            converged: s.converged,
            iterations: s.iterations as u64,
            error_indicator: s.error_indicator,
            qoi,
            wall_seconds: s.wall_seconds,
            solution_bytes: bytes.len() as u64,
            eta_history: s.history.clone(),
            work: s.work(),
            started_cold,
            contact: s.contact.iter().map(Into::into).collect(),
            qoi_largest: s
                .qoi
                .iter()
                .map(|(k, q)| (k.clone(), q.values.iter().fold(0.0f64, |m, v| m.max(v.abs()))))
                .collect(),
        };
        Delivery::Complete { header, bytes }
    }

    /// (study, point) it is about.
    pub fn point(&self) -> (u64, u64) {
        match self {
            Delivery::Fail(f) => (f.study_id, f.point_id),
            Delivery::Complete { header, .. } => (header.study_id, header.point_id),
        }
    }

    /// Sends it; the state the coordinator gave the point, for the log.
    pub async fn send(&self, client: &mut Pool) -> Result<v1::PointState, Status> {
        match self {
            Delivery::Fail(request) => {
                tracing::warn!(study = request.study_id, point = request.point_id, error = %request.error, "point failed");
                client.fail_point(request.clone()).await?;
                Ok(v1::PointState::Failed)
            }
            Delivery::Complete { header, bytes } => {
                let mut messages =
                    vec![v1::CompletePointMessage { body: Some(complete_point_message::Body::Header(header.clone())) }];
                messages.extend(
                    chunks(bytes)
                        .map(|c| v1::CompletePointMessage { body: Some(complete_point_message::Body::Chunk(c)) }),
                );
                let reply = client.complete_point(tokio_stream::iter(messages)).await?.into_inner();
                Ok(reply.point.map(|p| p.state()).unwrap_or_default())
            }
        }
    }

    /// `MAGIC`, a kind byte (0 fail, 1 complete), the message (length-prefixed), the solution.
    fn encode(&self) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        let (kind, message, bytes): (u8, Vec<u8>, &[u8]) = match self {
            Delivery::Fail(f) => (0, f.encode_to_vec(), &[]),
            Delivery::Complete { header, bytes } => (1, header.encode_to_vec(), bytes),
        };
        out.push(kind);
        for part in [&message[..], bytes] {
            out.extend_from_slice(&(part.len() as u64).to_le_bytes());
            out.extend_from_slice(part);
        }
        out
    }

    fn decode(data: &[u8]) -> Result<Self> {
        let rest = data.strip_prefix(MAGIC).context("not a glissade spool file")?;
        let (&kind, mut rest) = rest.split_first().context("truncated")?;
        let mut part = || -> Result<&[u8]> {
            let (len, tail) = rest.split_at_checked(8).context("truncated")?;
            let len = usize::try_from(u64::from_le_bytes(len.try_into().expect("8 bytes"))).context("length")?;
            let (body, tail) = tail.split_at_checked(len).context("truncated")?;
            rest = tail;
            Ok(body)
        };
        let message = part()?;
        let bytes = part()?;
        Ok(match kind {
            0 => Delivery::Fail(v1::FailPointRequest::decode(message)?),
            1 => Delivery::Complete { header: v1::CompletePointHeader::decode(message)?, bytes: bytes.to_vec() },
            k => bail!("unknown kind {k}"),
        })
    }
}

const MAGIC: &[u8] = b"GLISSADE-SPOOL-1\n";

/// The directory where a stopping pool leaves what it could not deliver.
#[derive(Debug, Clone)]
pub struct Spool {
    pub dir: PathBuf,
}

impl Spool {
    /// Writes `delivery` as a whole file or not at all (`io::write_atomically`).
    pub fn save(&self, delivery: &Delivery) -> Result<PathBuf> {
        std::fs::create_dir_all(&self.dir).with_context(|| format!("creating spool {}", self.dir.display()))?;
        let (study, point) = delivery.point();
        let path = self.dir.join(format!("study{study}-point{point}-{}.spool", std::process::id()));
        glissade_core::io::write_atomically(&path, |w| std::io::Write::write_all(w, &delivery.encode()))
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(path)
    }

    /// Spooled deliveries, oldest name first; unreadable files are reported and left alone.
    pub fn pending(&self) -> Vec<(PathBuf, Delivery)> {
        let Ok(entries) = std::fs::read_dir(&self.dir) else { return Vec::new() };
        let mut paths: Vec<PathBuf> =
            entries.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "spool")).collect();
        paths.sort();
        paths
            .into_iter()
            .filter_map(|p| match std::fs::read(&p).map_err(anyhow::Error::from).and_then(|d| Delivery::decode(&d)) {
                Ok(d) => Some((p, d)),
                Err(e) => {
                    tracing::error!(file = %p.display(), error = %format!("{e:#}"), "unreadable spool file left alone");
                    None
                }
            })
            .collect()
    }

    pub fn remove(path: &Path) {
        if let Err(e) = std::fs::remove_file(path) {
            tracing::warn!(file = %path.display(), error = %e, "cannot remove a delivered spool file");
        }
    }
}

/// Default spool: `$GLISSADE_SPOOL`, else `~/.glissade/spool`.
pub fn default_spool_dir() -> Option<PathBuf> {
    std::env::var_os("GLISSADE_SPOOL")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".glissade").join("spool")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spooled_delivery_reads_back_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let spool = Spool { dir: dir.path().join("spool") };
        let header = v1::CompletePointHeader { study_id: 3, point_id: 7, lease_id: u64::MAX, ..Default::default() };
        let complete = Delivery::Complete { header, bytes: vec![1, 2, 3, 255] };
        let fail =
            Delivery::Fail(v1::FailPointRequest { study_id: 3, point_id: 8, error: "x".into(), ..Default::default() });
        spool.save(&complete).unwrap();
        spool.save(&fail).unwrap();
        std::fs::write(spool.dir.join("junk.spool"), b"not ours").unwrap();
        let back: Vec<Delivery> = spool.pending().into_iter().map(|(_, d)| d).collect();
        assert_eq!(back, vec![complete, fail]);
        assert!(Delivery::decode(&MAGIC[..5]).is_err());
    }
}
