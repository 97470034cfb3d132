//! Sharded evaluation: shard K of N evaluates a deterministic, disjoint part of the seeded view
//! list (every N-th view starting at K, across all groups), so the union of the N shards is
//! exactly the views of a single run and every texture is still seen in the same views. Each
//! shard keeps its records in files of its own in the evaluation's cache ([`super::cache`]);
//! [`merge`] puts one texture's parts back together in the order a single run produces, after
//! checking that every shard is there once and that all were written with the same settings.
//!
//! Not a scheduler: the shards are plain processes (`cac eval --shard K/N`), started by Slurm,
//! Kubernetes, GNU parallel or by hand; `cac eval --merge` assembles the report.

use super::cache::{self, ShardHeader, ShardPart};
use super::run::{ImageRecord, TextureResult, ViewGroup};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::Path;

/// Shard `k` of `n` (`0 <= k < n`), written `K/N` on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub k: usize,
    pub n: usize,
}

impl std::str::FromStr for Shard {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Shard> {
        let (k, n) = s
            .split_once('/')
            .with_context(|| format!("shard {s:?}: expected K/N, e.g. 0/4 (shard 0 of 4)"))?;
        let k: usize = k
            .trim()
            .parse()
            .with_context(|| format!("shard {s:?}: K is not a whole number"))?;
        let n: usize = n
            .trim()
            .parse()
            .with_context(|| format!("shard {s:?}: N is not a whole number"))?;
        Shard::new(k, n)
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

impl Shard {
    /// Shard `k` of `n`; an error unless `0 <= k < n`.
    pub fn new(k: usize, n: usize) -> Result<Shard> {
        if n == 0 {
            bail!("shard {k}/{n}: N must be at least 1");
        }
        if k >= n {
            bail!(
                "shard {k}/{n} is out of range: shards of {n} are numbered 0 to {} (K/N with K < N)",
                n - 1
            );
        }
        Ok(Shard { k, n })
    }

    /// This shard's part of `views` (every N-th, starting at K): disjoint across shards, their
    /// union is `views`, and the order within a shard is the order of `views`.
    pub fn part<T: Copy>(&self, views: &[T]) -> Vec<T> {
        views.iter().skip(self.k).step_by(self.n).copied().collect()
    }
}

/// Puts one texture's shard files (in `dir`) back together. Refuses, naming the files: no shard
/// at all, a file written with other settings (its key is not `key`), shards of different
/// counts, a shard present twice, a shard missing, a file whose views are not its shard's.
/// Records come out in the order of a single run: group, view, then model in `models` order.
pub fn merge(
    dir: &Path,
    name: &str,
    key: &str,
    groups: &[ViewGroup],
    all_views: &[(usize, usize)],
    models: &[String],
) -> Result<(TextureResult, usize)> {
    // Check the files' numbers, keys and views first; read records and examples after.
    let parts = read_headers(dir, name, key)?;
    let (n, by_k) = complete_split(dir, name, &parts)?;
    check_views(&by_k, n, all_views)?;
    let out = assemble(&by_k, key, groups, models)?;
    Ok((out, n))
}

/// The headers of texture `name`'s shard files in `dir`; refuses none at all, and a file
/// written with other settings (its key is not `key`).
fn read_headers(dir: &Path, name: &str, key: &str) -> Result<Vec<ShardHeader>> {
    let files = cache::shard_files(dir, name)?;
    if files.is_empty() {
        bail!(
            "no shard of texture {name:?} in {}: run `cac eval --shard K/N` (K = 0 .. N-1) with the same arguments first",
            dir.display()
        );
    }
    let parts: Vec<ShardHeader> = files
        .iter()
        .map(|f| cache::read_shard_header(f))
        .collect::<Result<_>>()?;
    for p in &parts {
        if p.key != key {
            bail!(
                "{} was written with other settings than this merge (its cache key differs: the object, \
                 render settings, environment, views, protocol, models, examples or the texture itself \
                 changed); run the shards and the merge with the same arguments, or remove the file",
                p.path.display()
            );
        }
    }
    Ok(parts)
}

/// The shard count N and the headers by shard number K; refuses shards of different counts, a
/// shard present twice and a shard missing.
fn complete_split<'a>(
    dir: &Path,
    name: &str,
    parts: &'a [ShardHeader],
) -> Result<(usize, BTreeMap<usize, &'a ShardHeader>)> {
    let n = parts[0].shard.1;
    if let Some(o) = parts.iter().find(|p| p.shard.1 != n) {
        bail!(
            "the shards of texture {name:?} were split in different ways: {} is shard {} of {n}, {} is shard {} of {}; \
             remove the files of one split",
            parts[0].path.display(),
            parts[0].shard.0,
            o.path.display(),
            o.shard.0,
            o.shard.1
        );
    }
    let mut by_k: BTreeMap<usize, &ShardHeader> = BTreeMap::new();
    for p in parts {
        if let Some(first) = by_k.insert(p.shard.0, p) {
            bail!(
                "shard {}/{n} of texture {name:?} is present twice: {} and {}; remove one",
                p.shard.0,
                first.path.display(),
                p.path.display()
            );
        }
    }
    let missing: Vec<String> = (0..n)
        .filter(|k| !by_k.contains_key(k))
        .map(|k| {
            format!(
                "{k}/{n} ({})",
                dir.join(format!("{}.json", cache::shard_stem(name, k, n)))
                    .display()
            )
        })
        .collect();
    if !missing.is_empty() {
        bail!(
            "texture {name:?}: shard {} missing; run `cac eval --shard K/{n}` for each with the same arguments, then merge again",
            missing.join(", ")
        );
    }
    Ok((n, by_k))
}

/// Refuses a file whose views are not those of its shard of `all_views`.
fn check_views(
    by_k: &BTreeMap<usize, &ShardHeader>,
    n: usize,
    all_views: &[(usize, usize)],
) -> Result<()> {
    for (&k, p) in by_k {
        let want = Shard { k, n }.part(all_views);
        if p.views != want {
            bail!(
                "{} does not hold the views of shard {k}/{n} of this evaluation ({} views instead of {})",
                p.path.display(),
                p.views.len(),
                want.len()
            );
        }
    }
    Ok(())
}

/// Reads every shard's records and examples (refusing a file changed since its header was
/// read) and sorts them in the order of a single run.
fn assemble(
    by_k: &BTreeMap<usize, &ShardHeader>,
    key: &str,
    groups: &[ViewGroup],
    models: &[String],
) -> Result<TextureResult> {
    let mut out = TextureResult {
        records: vec![],
        skipped: 0,
        examples: vec![],
    };
    for p in by_k.values() {
        let mut part: ShardPart = cache::read_shard(&p.path)?;
        if part.key != key || part.shard != p.shard {
            bail!("{} changed while it was being merged", p.path.display());
        }
        out.records.append(&mut part.result.records);
        out.skipped += part.result.skipped;
        out.examples.append(&mut part.result.examples);
    }
    let group = |set, b| {
        groups
            .iter()
            .position(|g| g.set == set && g.brightness == b)
            .unwrap_or(usize::MAX)
    };
    let model = |m: &str| models.iter().position(|x| x == m).unwrap_or(usize::MAX);
    out.records
        .sort_by_key(|r: &ImageRecord| (group(r.set, r.brightness), r.view, model(&r.model)));
    out.examples
        .sort_by_key(|e| (group(e.set, e.brightness), e.view));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_split_the_view_list_disjointly_and_completely() {
        let views: Vec<(usize, usize)> = (0..4).flat_map(|g| (0..7).map(move |i| (g, i))).collect();
        for n in 1..=9 {
            let mut all: Vec<(usize, usize)> = (0..n)
                .flat_map(|k| Shard::new(k, n).unwrap().part(&views))
                .collect();
            assert_eq!(all.len(), views.len(), "n = {n}: overlap or gap");
            all.sort();
            assert_eq!(all, views, "n = {n}");
            // Balanced: part sizes differ by at most one.
            let sizes: Vec<usize> = (0..n)
                .map(|k| Shard::new(k, n).unwrap().part(&views).len())
                .collect();
            assert!(sizes.iter().max().unwrap() - sizes.iter().min().unwrap() <= 1);
        }
    }

    #[test]
    fn shard_numbers_are_checked() {
        assert_eq!("2/3".parse::<Shard>().unwrap(), Shard { k: 2, n: 3 });
        for (s, want) in [
            ("3/3", "out of range"),
            ("5/2", "numbered 0 to 1"),
            ("0/0", "at least 1"),
            ("1", "expected K/N"),
            ("a/2", "not a whole number"),
        ] {
            let e = format!("{:#}", s.parse::<Shard>().unwrap_err());
            assert!(e.contains(want), "{s}: {e}");
        }
    }
}
