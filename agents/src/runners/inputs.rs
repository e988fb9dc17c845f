//! The files a run's configuration names (a task's scene, recordings, posterior): their content
//! fingerprints in `<run>/inputs.toml`, written when the run is created, so that a resume or an
//! evaluation can tell that one was edited since. The run's own `config.toml` is checked
//! against its checkpoints already; these are what it points to.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::AgentError;

/// The run folder's file of input fingerprints.
pub const INPUTS_FILE: &str = "inputs.toml";

/// FNV-1a, 64 bits: a fingerprint against edits, not against an adversary.
pub(crate) struct Fnv(u64);

impl Fnv {
    pub(crate) fn new() -> Self {
        Self(0xcbf29ce484222325)
    }

    pub(crate) fn update(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            self.0 ^= byte as u64;
            self.0 = self.0.wrapping_mul(0x100000001b3);
        }
    }

    pub(crate) fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct InputsFile {
    #[serde(default, rename = "input")]
    inputs: Vec<Input>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Input {
    path: PathBuf,
    fingerprint: String,
}

/// The fingerprint of a file's bytes, or of a folder's files (names and bytes, in name order,
/// recursively).
pub fn fingerprint(path: &Path) -> std::io::Result<String> {
    let mut hash = Fnv::new();
    add(&mut hash, path, Path::new(""))?;
    Ok(hash.hex())
}

fn add(hash: &mut Fnv, path: &Path, relative: &Path) -> std::io::Result<()> {
    if path.is_dir() {
        let mut entries: Vec<PathBuf> = std::fs::read_dir(path)?
            .map(|e| e.map(|e| e.path()))
            .collect::<Result<_, _>>()?;
        entries.sort();
        for entry in entries {
            let name = entry.file_name().map(PathBuf::from).unwrap_or_default();
            add(hash, &entry, &relative.join(name))?;
        }
    } else {
        hash.update(relative.to_string_lossy().as_bytes());
        hash.update(&[0]);
        hash.update(&std::fs::read(path)?);
    }
    Ok(())
}

/// Records the fingerprints of `inputs` (files or folders that exist) in `run_dir`.
pub fn record_inputs(run_dir: &Path, inputs: &[PathBuf]) -> Result<(), AgentError> {
    let inputs = inputs
        .iter()
        .map(|path| {
            Ok(Input {
                fingerprint: fingerprint(path).map_err(|e| AgentError::io(path, e))?,
                path: path.clone(),
            })
        })
        .collect::<Result<Vec<_>, AgentError>>()?;
    let text = toml::to_string(&InputsFile { inputs }).expect("paths and strings serialise");
    let path = run_dir.join(INPUTS_FILE);
    rlpkg_files::write_atomic(&path, text.as_bytes()).map_err(|e| AgentError::io(&path, e))
}

/// The recorded inputs of `run_dir` whose content is not what it was when the run was created
/// (or that are gone); none when the run recorded none.
pub fn changed_inputs(run_dir: &Path) -> Result<Vec<PathBuf>, AgentError> {
    let path = run_dir.join(INPUTS_FILE);
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(AgentError::io(&path, e)),
    };
    let file: InputsFile = toml::from_str(&text).map_err(|e| AgentError::Checkpoint {
        path: path.clone(),
        reason: format!("not a list of input fingerprints: {e}"),
    })?;
    Ok(file
        .inputs
        .into_iter()
        .filter(|input| fingerprint(&input.path).ok().as_ref() != Some(&input.fingerprint))
        .map(|input| input.path)
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_edited_file_or_folder_is_named_and_an_untouched_one_is_not() {
        let dir = tempfile::tempdir().unwrap();
        let (run, scene, data) = (
            dir.path().join("run"),
            dir.path().join("scene.toml"),
            dir.path().join("data"),
        );
        std::fs::create_dir_all(run.clone()).unwrap();
        std::fs::create_dir_all(data.join("take")).unwrap();
        std::fs::write(&scene, "mu_con = 0.6\n").unwrap();
        std::fs::write(data.join("take/markers.csv"), "t,x\n0,1\n").unwrap();
        assert!(changed_inputs(&run).unwrap().is_empty(), "nothing recorded");
        record_inputs(&run, &[scene.clone(), data.clone()]).unwrap();
        assert!(changed_inputs(&run).unwrap().is_empty());
        std::fs::write(&scene, "mu_con = 2.5\n").unwrap();
        assert_eq!(changed_inputs(&run).unwrap(), vec![scene.clone()]);
        std::fs::write(&scene, "mu_con = 0.6\n").unwrap();
        std::fs::write(data.join("take/markers.csv"), "t,x\n0,2\n").unwrap();
        assert_eq!(changed_inputs(&run).unwrap(), vec![data.clone()]);
        std::fs::write(data.join("take/markers.csv"), "t,x\n0,1\n").unwrap();
        std::fs::rename(data.join("take"), data.join("other")).unwrap();
        assert_eq!(
            changed_inputs(&run).unwrap(),
            vec![data.clone()],
            "a renamed take"
        );
        std::fs::remove_file(&scene).unwrap();
        assert!(
            changed_inputs(&run).unwrap().contains(&scene),
            "a removed file"
        );
    }
}
