//! Splitting a library among N workers that share nothing but a file system: a material goes
//! to the shard its relative path hashes to, so every worker computes the same split alone.

use std::fmt;
use std::str::FromStr;

use sha2::{Digest, Sha256};

use matup_core::{Error, Result};

/// Shard `index` of `count` (0-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    pub fn new(index: usize, count: usize) -> Result<Shard> {
        if count == 0 || index >= count {
            return Err(Error::Invalid(format!(
                "shard {index}/{count}: the index must be below the count (shards are numbered from 0)"
            )));
        }
        Ok(Shard { index, count })
    }

    /// Whether this shard takes the material at `relative` (its '/'-separated path under the
    /// library). SHA-256 rather than std's hasher, which may change between Rust releases,
    /// and workers built at different times must agree.
    pub fn takes(&self, relative: &str) -> bool {
        let digest = Sha256::digest(relative.as_bytes());
        let head = u64::from_be_bytes(digest[..8].try_into().expect("8 bytes"));
        (head % self.count as u64) as usize == self.index
    }

    /// The shard a scheduler assigned, read through `var` (the process environment in the
    /// CLI): a Slurm job array (`SLURM_ARRAY_TASK_ID` from `SLURM_ARRAY_TASK_MIN`, of
    /// `SLURM_ARRAY_TASK_COUNT`, or of `shards` when given) or a Kubernetes Indexed Job
    /// (`JOB_COMPLETION_INDEX`, of `shards`, which Kubernetes does not export). `None` when
    /// neither is set.
    pub fn from_scheduler(
        var: impl Fn(&str) -> Option<String>,
        shards: Option<usize>,
    ) -> Result<Option<Shard>> {
        let number = |name: &str| -> Result<Option<usize>> {
            var(name)
                .map(|v| {
                    v.trim().parse::<usize>().map_err(|_| {
                        Error::Invalid(format!("{name}={v:?} is not a non-negative whole number"))
                    })
                })
                .transpose()
        };
        if let Some(task) = number("SLURM_ARRAY_TASK_ID")? {
            let first = number("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
            let count = match shards {
                Some(n) => n,
                None => number("SLURM_ARRAY_TASK_COUNT")?.ok_or_else(|| {
                    Error::Invalid(
                        "SLURM_ARRAY_TASK_ID is set but SLURM_ARRAY_TASK_COUNT is not; pass --shards N"
                            .into(),
                    )
                })?,
            };
            let index = task.checked_sub(first).ok_or_else(|| {
                Error::Invalid(format!(
                    "SLURM_ARRAY_TASK_ID {task} is below SLURM_ARRAY_TASK_MIN {first}"
                ))
            })?;
            return Shard::new(index, count).map(Some);
        }
        if let Some(index) = number("JOB_COMPLETION_INDEX")? {
            let count = shards.ok_or_else(|| {
                Error::Invalid(
                    "JOB_COMPLETION_INDEX is set (a Kubernetes Indexed Job); pass --shards N with the job's completions"
                        .into(),
                )
            })?;
            return Shard::new(index, count).map(Some);
        }
        Ok(None)
    }
}

impl FromStr for Shard {
    type Err = Error;

    /// `I/N`, e.g. `0/3`.
    fn from_str(s: &str) -> Result<Shard> {
        let bad = || Error::Invalid(format!("--shard '{s}': expected I/N, e.g. 0/3"));
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let index = i.trim().parse().map_err(|_| bad())?;
        let count = n.trim().parse().map_err(|_| bad())?;
        Shard::new(index, count)
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    #[test]
    fn shards_partition_a_library() {
        let names: Vec<String> = (0..300).map(|i| format!("wood/oak_{i:03}")).collect();
        let shards: Vec<Shard> = (0..3).map(|i| Shard::new(i, 3).unwrap()).collect();
        let mut sizes = [0; 3];
        for name in &names {
            let owners: Vec<usize> = shards
                .iter()
                .filter(|s| s.takes(name))
                .map(|s| s.index)
                .collect();
            assert_eq!(owners.len(), 1, "{name} must go to exactly one shard");
            sizes[owners[0]] += 1;
        }
        // A hash spreads 300 names about evenly: each shard within 100 ± 30.
        assert!(sizes.iter().all(|&n| (70..=130).contains(&n)), "{sizes:?}");
    }

    #[test]
    fn the_split_is_stable() {
        // Pinned: workers built by different compilers must split a library the same way.
        let owner = |name: &str| (0..4).find(|&i| Shard::new(i, 4).unwrap().takes(name));
        let got: Vec<_> = ["a", "wood/oak", "metal/plate 02"].map(owner).into();
        let again: Vec<_> = ["a", "wood/oak", "metal/plate 02"].map(owner).into();
        assert_eq!(got, again);
        // SHA-256("a") begins 0xca978112ca1bbdca; that mod 4 is 2.
        assert_eq!(got[0], Some(2));
    }

    #[test]
    fn parses_and_rejects() {
        assert_eq!("1/3".parse::<Shard>().unwrap(), Shard::new(1, 3).unwrap());
        for bad in ["3/3", "1", "a/3", "0/0"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    #[test]
    fn reads_slurm_and_kubernetes() {
        let env = |pairs: &[(&str, &str)]| {
            let map: HashMap<String, String> = pairs
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect();
            move |k: &str| map.get(k).cloned()
        };
        let slurm = env(&[
            ("SLURM_ARRAY_TASK_ID", "5"),
            ("SLURM_ARRAY_TASK_MIN", "1"),
            ("SLURM_ARRAY_TASK_COUNT", "8"),
        ]);
        assert_eq!(
            Shard::from_scheduler(&slurm, None).unwrap(),
            Some(Shard::new(4, 8).unwrap())
        );
        let k8s = env(&[("JOB_COMPLETION_INDEX", "2")]);
        assert_eq!(
            Shard::from_scheduler(&k8s, Some(3)).unwrap(),
            Some(Shard::new(2, 3).unwrap())
        );
        let err = Shard::from_scheduler(&k8s, None).unwrap_err().to_string();
        assert!(err.contains("--shards"), "{err}");
        assert_eq!(Shard::from_scheduler(env(&[]), None).unwrap(), None);
    }
}
