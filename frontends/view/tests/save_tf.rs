//! The `T` key saves the transfer function on screen as a JSON file that holds exactly
//! the `--opacity`/`--color`/mode/shading of the `shearwarp render` arguments the viewer
//! prints for the same view (the file frontend's tests show that `--tf FILE` renders like
//! those options).

use shearwarp_file::tffile::{TfSpec, Units};
use shearwarp_view::preset;
use std::path::Path;
use std::process::Command;

/// The value of `--NAME VALUE` in a printed argument list.
fn arg<'a>(args: &'a str, name: &str) -> Option<&'a str> {
    let mut it = args.split_whitespace();
    while let Some(a) = it.next() {
        if a == name {
            return it.next();
        }
    }
    None
}

#[test]
fn saved_transfer_functions_match_the_printed_cli_arguments() {
    let dir = std::env::temp_dir().join(format!("shearwarp-view-tf-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let script = dir.join("s.txt");
    // MR brain with a changed window and level; then CT bone as MIP; then shading off.
    std::fs::write(
        &script,
        "key 2\nkey ]\nkey .\nkey t\nkey 3\nkey m\nkey t\nkey m\nkey l\nkey t\nsettle\n",
    )
    .unwrap();
    let fixture =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/mr_head_colin27_64.json");
    let out = Command::new(env!("CARGO_BIN_EXE_shearwarp-view"))
        .arg(&fixture)
        .args([
            "--no-window",
            "--size",
            "48x48",
            "--threads",
            "1",
            "--shot-prefix",
        ])
        .arg(dir.join("v"))
        .arg("--script")
        .arg(&script)
        .arg("--dump")
        .arg(dir.join("d.png"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<&str> = stdout.lines().collect();
    let mut saved = 0;
    for (i, l) in lines.iter().enumerate() {
        let Some(file) = l.strip_prefix("wrote ").filter(|f| f.ends_with(".json")) else {
            continue;
        };
        saved += 1;
        let cli = lines[i + 1].strip_prefix("cli-args: ").unwrap();
        let spec = TfSpec::load(Path::new(file)).unwrap();
        assert_eq!(spec.units, Units::Raw);
        assert_eq!(
            Some(preset::opacity_spec(&spec.opacity).as_str()),
            arg(cli, "--opacity"),
            "{file}"
        );
        let color = spec.color.as_deref().unwrap();
        assert_eq!(
            Some(preset::color_spec(color).as_str()),
            arg(cli, "--color"),
            "{file}"
        );
        assert_eq!(spec.mip, cli.contains("--mode mip"), "{file}: {cli}");
        assert_eq!(
            spec.shading == Some(true),
            cli.contains("--shading"),
            "{file}: {cli}"
        );
        match saved {
            1 => assert!(!spec.mip && spec.shading == Some(true)),
            2 => assert!(spec.mip),
            _ => assert!(!spec.mip && spec.shading == Some(false)),
        }
    }
    assert_eq!(saved, 3, "{stdout}");
    // Different views saved different functions.
    let a = std::fs::read_to_string(dir.join("v-tf-001.json")).unwrap();
    let b = std::fs::read_to_string(dir.join("v-tf-002.json")).unwrap();
    assert_ne!(a, b);
    let _ = std::fs::remove_dir_all(&dir);
}
