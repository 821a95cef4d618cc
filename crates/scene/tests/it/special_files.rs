//! A scene file, or a volume a scene names, that is a FIFO, a directory or a device is refused
//! at once, naming the path and what it is — through `Scene::from_file`, for every volume
//! format. Reading a FIFO would otherwise block forever: every load runs on a thread the test
//! stops waiting for after a few seconds.

#![cfg(unix)]

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

use scene::{Scene, SceneError};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("volrad-special-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn mkfifo(p: &Path) {
    let made = std::process::Command::new("mkfifo")
        .arg(p)
        .status()
        .unwrap();
    assert!(made.success(), "mkfifo {}", p.display());
}

/// Loads each scene on one thread; returns each result, failing if one does not come back
/// within 10 s (a read blocked on a FIFO).
fn load_all(scenes: Vec<PathBuf>) -> Vec<(PathBuf, Result<Scene, SceneError>)> {
    let count = scenes.len();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for s in scenes {
            let r = Scene::from_file(&s);
            let _ = tx.send((s, r));
        }
    });
    (0..count)
        .map(|_| {
            rx.recv_timeout(Duration::from_secs(10))
                .expect("refused at once, not blocked reading a FIFO")
        })
        .collect()
}

const REST: &str = "[medium]\nalbedo = 0.5\n[[light]]\nkind = \"directional\"\ndirection = [0.0, -1.0, 0.0]\nirradiance = 1.0\n";

#[test]
fn a_scene_file_that_is_a_fifo_or_a_directory_is_refused() {
    let dir = scratch("scene");
    let fifo = dir.join("fifo.toml");
    mkfifo(&fifo);
    let folder = dir.join("folder.toml");
    std::fs::create_dir(&folder).unwrap();
    let results = load_all(vec![fifo.clone(), folder.clone(), "/dev/null".into()]);
    let expected = [
        (fifo, "is a FIFO, not a regular file"),
        (folder, "is a directory, not a regular file"),
        (
            "/dev/null".into(),
            "is a character device, not a regular file",
        ),
    ];
    for ((path, result), (want_path, what)) in results.into_iter().zip(expected) {
        assert_eq!(path, want_path);
        match result {
            Err(e @ SceneError::Io { .. }) => {
                assert_eq!(e.to_string(), format!("{}: {what}", path.display()))
            }
            other => panic!("{}: expected an I/O error, got {other:?}", path.display()),
        }
    }
}

#[test]
fn a_volume_that_is_a_fifo_or_a_directory_is_refused_in_every_format() {
    let dir = scratch("volume");
    let mut scenes = Vec::new();
    let mut expected = Vec::new();
    for name in [
        "density.f32",
        "density.vol",
        "density.nrrd",
        "density.nii",
        "density.nii.gz",
        "density.vdb",
    ] {
        for (kind, what) in [
            ("fifo", "is a FIFO, not a regular file"),
            ("folder", "is a directory, not a regular file"),
        ] {
            let volume = dir.join(format!("{kind}-{name}"));
            if kind == "fifo" {
                mkfifo(&volume);
            } else {
                std::fs::create_dir(&volume).unwrap();
            }
            let scene = dir.join(format!("{kind}-{name}.toml"));
            std::fs::write(
                &scene,
                format!("[volume]\nfile = \"{kind}-{name}\"\ndims = [1, 1, 1]\n{REST}"),
            )
            .unwrap();
            scenes.push(scene);
            expected.push((volume, what));
        }
    }
    // A detached NRRD header whose data file is a FIFO.
    let data = dir.join("data.raw");
    mkfifo(&data);
    std::fs::write(
        dir.join("detached.nhdr"),
        "NRRD0004\ntype: float\ndimension: 3\nsizes: 1 1 1\nendian: little\nencoding: raw\ndata file: data.raw\n",
    )
    .unwrap();
    let scene = dir.join("detached.toml");
    std::fs::write(
        &scene,
        format!("[volume]\nfile = \"detached.nhdr\"\n{REST}"),
    )
    .unwrap();
    scenes.push(scene);
    expected.push((data, "is a FIFO, not a regular file"));

    for ((scene, result), (volume, what)) in load_all(scenes).into_iter().zip(expected) {
        let err = result.expect_err(&format!("{} names no volume", scene.display()));
        let msg = err.to_string();
        match err {
            SceneError::Invalid { key, .. } => assert_eq!(key, "volume.file", "{msg}"),
            other => panic!("expected a scene error, got {other:?}"),
        }
        assert!(
            msg.ends_with(&format!("{}: {what}", volume.display())),
            "{}: {msg}",
            scene.display()
        );
    }
}
