//! `glissade fields`' arguments and design point, shared by the CLI (which hands the command to
//! `glissade-worker fields`: the re-solve needs the solver and HDF5, which the CLI does not link)
//! and the worker (which runs it).

use std::ffi::OsString;
use std::path::PathBuf;

use anyhow::{Context, Result, anyhow, bail};
use glissade_core::point::DesignPoint;

#[derive(Debug, Clone, clap::Args)]
pub struct FieldsArgs {
    /// The study id.
    pub study: u64,
    /// The design point, every swept parameter: NAME=VALUE,NAME=VALUE (need not be a point of
    /// the study: it is solved from the nearest one).
    #[arg(long, value_name = "NAME=VALUE,...")]
    pub point: String,
    /// HDF5 file to write; the XDMF file ParaView opens goes beside it (OUT.xdmf).
    #[arg(long, value_name = "OUT.h5")]
    pub out: PathBuf,
    /// Directory of the scene's mesh files, for a scene with mesh bodies (the coordinator does
    /// not hand them to users): they must be the study's, checked by the scene hash.
    #[arg(long, value_name = "DIR")]
    pub meshes: Option<PathBuf>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

impl FieldsArgs {
    /// The arguments as given (what `glissade-worker fields` parses back).
    pub fn to_args(&self) -> Vec<OsString> {
        let mut args: Vec<OsString> =
            vec![self.study.to_string().into(), "--point".into(), self.point.clone().into(), "--out".into()];
        args.push(self.out.clone().into());
        if let Some(dir) = &self.meshes {
            args.extend(["--meshes".into(), dir.clone().into()]);
        }
        if self.json {
            args.push("--json".into());
        }
        args
    }
}

/// Where the coordinator is and how to present oneself to it: the options every command of the
/// CLI takes, and `glissade-worker fields` too.
#[derive(Debug, Clone, clap::Args)]
pub struct ServerArgs {
    /// URL of the glissade coordinator (glissade-server).
    #[arg(long, global = true, env = "GLISSADE_SERVER", value_name = "URL", default_value = "http://127.0.0.1:50051")]
    pub server: String,
    /// File holding the user token of a coordinator that asks for one (else GLISSADE_TOKEN,
    /// else the file GLISSADE_TOKEN_FILE names).
    #[arg(long, global = true, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// PEM certificate of the authority that signed an https:// coordinator's certificate
    /// (else GLISSADE_CA_CERT, else the system's roots).
    #[arg(long, global = true, value_name = "FILE")]
    pub ca_cert: Option<PathBuf>,
}

impl ServerArgs {
    /// The options as given (the token itself is never on a command line).
    pub fn to_args(&self) -> Vec<OsString> {
        let mut args: Vec<OsString> = vec!["--server".into(), self.server.clone().into()];
        if let Some(f) = &self.token_file {
            args.extend(["--token-file".into(), f.clone().into()]);
        }
        if let Some(f) = &self.ca_cert {
            args.extend(["--ca-cert".into(), f.clone().into()]);
        }
        args
    }

    /// The coordinator these options name, with its token read.
    pub fn server(&self) -> Result<crate::connect::Server> {
        let token = glissade_proto::auth::Token::for_client(self.token_file.as_deref())?;
        Ok(crate::connect::Server { url: self.server.clone(), token, ca_cert: self.ca_cert.clone() })
    }
}

/// `f1=0.12,f2=0.15` with exactly the swept parameters, finite values (`flag` names the option).
pub fn parse_point(flag: &str, spec: &str, swept: &[String]) -> Result<DesignPoint> {
    let mut point = DesignPoint::new();
    for pair in spec.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (name, value) = pair.split_once('=').ok_or_else(|| anyhow!("{flag} {spec}: `{pair}` is not NAME=VALUE"))?;
        let value: f64 =
            value.trim().parse().map_err(|_| anyhow!("{flag} {spec}: `{}` is not a number", value.trim()))?;
        if !value.is_finite() {
            bail!("{flag} {spec}: {name} must be finite");
        }
        if !swept.iter().any(|s| s == name.trim()) {
            bail!("{flag} {spec}: `{}` is not a swept parameter of the study ({})", name.trim(), swept.join(", "));
        }
        if point.get(name.trim()).is_some() {
            bail!("{flag} {spec}: {name} given twice");
        }
        point.insert(name.trim(), value).with_context(|| format!("{flag} {spec}"))?;
    }
    if point.len() != swept.len() {
        bail!("{flag} {spec}: give every swept parameter ({})", swept.join(", "));
    }
    Ok(point)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_gives_every_swept_parameter_once() {
        let swept = ["f1".to_owned(), "f2".to_owned()];
        let p = parse_point("--point", "f1=0.12, f2=0.15", &swept).unwrap();
        assert_eq!(p, DesignPoint::from_pairs([("f1", 0.12), ("f2", 0.15)]).unwrap());
        for bad in ["f1=0.12", "f1=0.1,f2=x", "f1=0.1,f3=0.1", "f1=0.1,f1=0.2", "f1=0.1,f2=inf", "f1"] {
            assert!(parse_point("--at", bad, &swept).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_arguments_handed_on_parse_back_to_the_same() {
        #[derive(clap::Parser)]
        struct Both {
            #[command(flatten)]
            fields: FieldsArgs,
            #[command(flatten)]
            server: ServerArgs,
        }
        use clap::Parser;
        let given = ["x", "7", "--point", "f1=0.1,f2=0.2", "--out", "a b/p.h5", "--meshes", "m", "--json"];
        let both = Both::try_parse_from(given.iter().chain(&["--server", "http://h:1", "--token-file", "t"])).unwrap();
        let again: Vec<OsString> =
            std::iter::once("x".into()).chain(both.fields.to_args()).chain(both.server.to_args()).collect();
        let back = Both::try_parse_from(again).unwrap();
        assert_eq!(format!("{:?} {:?}", back.fields, back.server), format!("{:?} {:?}", both.fields, both.server));
    }
}
