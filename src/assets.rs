//! Where the shared data lives (feature `tools`): the MakeHuman body, garments and motion clips (an
//! `assets` folder, laid out as `../shared/assets` of the source checkout) and the reference
//! implementation's parity fixtures (a `fixtures` folder beside it).
//!
//! Nothing is compiled in: the folder comes from the caller (`--assets DIR` on the command
//! line), else from the environment variable [`ENV`], else from a `shared/assets` folder in the
//! working directory or one of its ancestors (which finds `../shared/assets` beside a checkout
//! when run from inside it).

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};
use std::string::{String, ToString};

/// The environment variable naming the assets folder.
pub const ENV: &str = "HOOD_ASSETS";

/// How many ancestors of the working directory [`locate`] looks in for `shared/assets`.
const SEARCH_DEPTH: usize = 4;

/// The assets folder: `given` when it is `Some`, else the folder [`ENV`] names, else the first
/// `shared/assets` found in the working directory and up to four of its ancestors.
///
/// # Errors
/// [`Error::Io`] when the folder given (or named by [`ENV`]) is not a folder, or when none is
/// given and the search finds none; the message says how to name one.
pub fn locate(given: Option<&Path>) -> Result<PathBuf> {
    let from_env = std::env::var_os(ENV).filter(|v| !v.is_empty()).map(PathBuf::from);
    if let Some((dir, source)) = given.map(|d| (d.to_path_buf(), "--assets")).or(from_env.map(|d| (d, ENV))) {
        return if dir.is_dir() { Ok(dir) } else { Err(not_a_folder(&dir, source)) };
    }
    let cwd = std::env::current_dir().map_err(|e| Error::io(Path::new("."), e))?;
    cwd.ancestors().take(SEARCH_DEPTH + 1).map(|d| d.join("shared").join("assets")).find(|d| d.is_dir()).ok_or_else(
        || Error::Io {
            path: String::from("assets"),
            message: std::format!(
                "no assets folder: pass --assets DIR or set {ENV} (the MakeHuman body, garments and \
                 motions; no shared/assets in {} or its parents)",
                cwd.display()
            ),
        },
    )
}

/// The parity-fixtures folder beside `assets` (`assets/../fixtures`).
pub fn fixtures(assets: &Path) -> PathBuf {
    assets.parent().unwrap_or(assets).join("fixtures")
}

fn not_a_folder(dir: &Path, source: &str) -> Error {
    Error::Io { path: dir.display().to_string(), message: std::format!("not a folder (from {source})") }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_given_folder_wins_and_a_missing_one_is_refused() {
        let dir = std::env::temp_dir();
        assert_eq!(locate(Some(&dir)).unwrap(), dir);
        let missing = dir.join("hood-no-such-assets-folder");
        let e = locate(Some(&missing)).unwrap_err();
        assert!(matches!(&e, Error::Io { path, .. } if path.contains("hood-no-such-assets-folder")), "{e}");
    }

    #[test]
    fn fixtures_sit_beside_the_assets() {
        assert_eq!(fixtures(Path::new("/data/shared/assets")), Path::new("/data/shared/fixtures"));
    }
}
