//! The `shearwarp` command line: presets, transfer-function files, windows, 16-bit PNG,
//! turntables, --json/--quiet, and exit code 2 with a one-line error for bad input.

use shearwarp_file::tffile::{TfSpec, Units};
use std::path::{Path, PathBuf};
use std::process::Command;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
}

fn head64() -> String {
    fixtures()
        .join("mr_head_colin27_64.json")
        .to_string_lossy()
        .into_owned()
}

fn shared(name: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(name);
    p.exists().then_some(p)
}

struct Tmp(PathBuf);

impl Tmp {
    fn new(tag: &str) -> Tmp {
        let d = std::env::temp_dir().join(format!("shearwarp-cli-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Tmp(d)
    }
    fn p(&self, name: &str) -> String {
        self.0.join(name).to_string_lossy().into_owned()
    }
}

impl Drop for Tmp {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn shearwarp(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_shearwarp"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs a render that must succeed; returns its RGB pixels.
fn render(args: &[&str], out: &str) -> Vec<u8> {
    let mut a = vec![
        "render",
        "--size",
        "96x96",
        "--rotate-x",
        "-70",
        "--rotate-y",
        "-35",
    ];
    a.extend_from_slice(args);
    a.extend_from_slice(&["-o", out]);
    let (code, _, err) = shearwarp(&a);
    assert_eq!(code, 0, "{a:?}: {err}");
    let img = image::open(out).unwrap().to_rgb8();
    assert!(img.as_raw().iter().any(|&v| v > 20), "{a:?}: empty image");
    img.into_raw()
}

#[test]
fn every_isa_level_renders_the_same_png() {
    let t = Tmp::new("isa");
    let args = |isa: &'static str| [head64(), "--shading".into(), "--isa".into(), isa.into()];
    let base = args("baseline");
    let base: Vec<&str> = base.iter().map(String::as_str).collect();
    let want = render(&base, &t.p("base.png"));
    // A level the CPU lacks falls back to the highest one it has, so both always run.
    for isa in ["x86-64-v3", "x86-64-v4"] {
        let a = args(isa);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        assert!(render(&a, &t.p(&format!("{isa}.png"))) == want, "{isa}");
    }
}

/// `--crop`: a box of the whole volume (bounds left out) changes nothing; a half box
/// changes the picture in the classified and the unclassified modes, and at a level of
/// detail; a box encoded into a `.swv` renders as the same box given at render time.
#[test]
fn crop_boxes_from_the_command_line() {
    let t = Tmp::new("crop");
    let h = head64();
    for mode in ["composite", "post"] {
        let with = |crop: Option<&str>, name: &str| {
            let mut a = vec![h.as_str(), "--shading", "--mode", mode];
            if let Some(c) = crop {
                a.extend(["--crop", c]);
            }
            render(&a, &t.p(&format!("{mode}-{name}.png")))
        };
        let plain = with(None, "plain");
        assert!(with(Some(",,"), "every") == plain, "{mode}: the whole box");
        assert!(
            with(Some("0:63,:,0:"), "bounds") == plain,
            "{mode}: the edges"
        );
        assert!(with(Some(":31,,"), "half") != plain, "{mode}: half of x");
    }
    let half = render(&[&h, "--crop", ":31,,"], &t.p("half.png"));
    let swv = t.p("half.swv");
    let (code, _, err) = shearwarp(&["encode", &h, "--crop", ":31,,", "-o", &swv]);
    assert_eq!(code, 0, "{err}");
    assert!(render(&[&swv], &t.p("half-swv.png")) == half, "encoded box");
    let level = render(&[&h, "--lod", "1", "--crop", ":31,,"], &t.p("lod.png"));
    assert!(level != render(&[&h, "--lod", "1"], &t.p("lod-plain.png")));
}

/// `--clip`: a plane at offset 1 (touching the volume's far corner) changes nothing; an
/// axis plane through the centre cuts the classified volume where `--crop` does; an oblique
/// one changes the picture in every mode and at a level of detail; planes encoded into
/// a `.swv` render as the same planes given at render time.
#[test]
fn clipping_planes_from_the_command_line() {
    let t = Tmp::new("clip");
    let h = head64();
    let run = |extra: &[&str], name: &str| {
        let mut a = vec![h.as_str(), "--shading"];
        a.extend(extra);
        render(&a, &t.p(&format!("{name}.png")))
    };
    for mode in ["composite", "post"] {
        let m = ["--mode", mode];
        let plain = run(&m, &format!("{mode}-plain"));
        let far = run(
            &[&m[..], &["--clip", "1,0.5,-0.8:1"]].concat(),
            &format!("{mode}-far"),
        );
        assert!(far == plain, "{mode}: a plane past the volume");
        // x = 31.5 between voxels 31 and 32 of 64: exactly the box x ≤ 31.
        let plane = run(
            &[&m[..], &["--clip", "1,0,0"]].concat(),
            &format!("{mode}-x"),
        );
        let boxed = run(
            &[&m[..], &["--crop", ":31,,"]].concat(),
            &format!("{mode}-box"),
        );
        // Classified, voxel 31 keeps all its opacity and 32 none: the box's voxels.
        // Per sample, the plane fades the samples between them, which the box keeps or
        // cuts whole.
        assert_eq!(
            plane == boxed,
            mode == "composite",
            "{mode}: the plane and the box"
        );
        assert!(plane != plain, "{mode}: the axis plane cuts");
        // One plane inverted keeps what the plane turned round keeps, to the bit.
        let inverted = [&m[..], &["--clip", "1,0.5,0.8:0.2", "--clip-invert"]].concat();
        let turned = [&m[..], &["--clip=-1,-0.5,-0.8:-0.2"]].concat();
        let a = run(&inverted, &format!("{mode}-inverted"));
        assert!(
            a == run(&turned, &format!("{mode}-turned")),
            "{mode}: inverted"
        );
        assert!(a != plain, "{mode}: the inverted plane cuts");
    }
    for mode in ["preint", "iso"] {
        let m = ["--mode", mode, "--iso", "60"];
        let plain = run(&m, &format!("{mode}-plain"));
        let cut = run(&[&m[..], &["--clip", "1,0.5,0.8:-0.2"]].concat(), mode);
        assert!(cut != plain, "{mode}: an oblique plane cuts");
    }
    let two = ["--clip", "1,0.5,0.8:0.3", "--clip", "-1,-0.5,-0.8:0.3"];
    let slab = render(&[&[h.as_str()][..], &two].concat(), &t.p("slab.png"));
    let swv = t.p("slab.swv");
    let mut a = vec!["encode", h.as_str(), "-o", swv.as_str()];
    a.extend(two);
    let (code, _, err) = shearwarp(&a);
    assert_eq!(code, 0, "{err}");
    assert!(
        render(&[&swv], &t.p("slab-swv.png")) == slab,
        "encoded planes"
    );
    // A .swv encoded whole is cut as it is composited: an axis plane between voxels
    // to the bit as the planes baked in cut it (no voxel lies on a ramp), inverted or
    // not; an oblique slab to within a few levels (the voxels on the ramps are scaled
    // after shading instead of before).
    let whole = t.p("whole.swv");
    let (code, _, err) = shearwarp(&["encode", h.as_str(), "-o", whole.as_str(), "--shading"]);
    assert_eq!(code, 0, "{err}");
    let x = ["--clip", "1,0,0"];
    let live = render(&[&[whole.as_str()][..], &x].concat(), &t.p("x-live.png"));
    assert!(live == run(&x, "x-baked"), "an axis plane cut live");
    let inverted = ["--clip", "1,0,0", "--clip-invert"];
    let live = render(
        &[&[whole.as_str()][..], &inverted].concat(),
        &t.p("x-live-inverted.png"),
    );
    assert!(
        live == run(&["--clip=-1,0,0"], "x-turned"),
        "inverted, live"
    );
    let live = render(
        &[&[whole.as_str()][..], &two].concat(),
        &t.p("slab-live.png"),
    );
    let baked = run(&two, "slab-baked");
    let worst = live.iter().zip(&baked).map(|(a, b)| a.abs_diff(*b)).max();
    assert!(
        worst.is_some_and(|e| (1..=8).contains(&e)),
        "slab live: {worst:?}"
    );
    let level = run(&["--lod", "1", "--clip", "0,1,1"], "lod");
    assert!(level != run(&["--lod", "1"], "lod-plain"));
    // `--clip-face`: the cut's face lit by the plane changes the picture, classified
    // and per sample; on a .swv cut live, as the baked planes light it, to the bit
    // (an axis plane between voxels), inverted or not.
    for mode in ["composite", "post"] {
        let cut = [&["--mode", mode][..], &x].concat();
        let lit = run(&[&cut[..], &["--clip-face", "2"]].concat(), "face");
        assert!(lit != run(&cut, "face-plain"), "{mode}: the face is lit");
    }
    for extra in [&[][..], &["--clip-invert"]] {
        let lit = [&x[..], &["--clip-face", "1.5"], extra].concat();
        let live = render(
            &[&[whole.as_str()][..], &lit].concat(),
            &t.p("face-live.png"),
        );
        assert!(
            live == run(&lit, "face-baked"),
            "a lit face cut live {extra:?}"
        );
    }
}

#[test]
fn unclassified_modes_render_the_same_png_on_any_thread_count() {
    let t = Tmp::new("post-threads");
    for mode in ["post", "preint", "iso"] {
        let run = |threads: &str| {
            let head = head64();
            let mut a = vec![
                head.as_str(),
                "--shading",
                "--mode",
                mode,
                "--threads",
                threads,
            ];
            if mode == "iso" {
                a.extend_from_slice(&["--iso", "80"]);
            }
            render(&a, &t.p(&format!("{mode}-{threads}.png")))
        };
        let one = run("1");
        for threads in ["2", "3"] {
            assert!(run(threads) == one, "--mode {mode} --threads {threads}");
        }
    }
}

#[test]
fn a_saved_tf_file_renders_like_the_same_options() {
    let t = Tmp::new("tf");
    let spec = TfSpec {
        units: Units::Raw,
        mip: false,
        shading: Some(true),
        opacity: vec![(40.0, 0.0), (90.0, 0.05), (200.0, 0.6)],
        color: Some(vec![
            (40.0, [0x90, 0x40, 0x30]),
            (220.0, [0xff, 0xf0, 0xe0]),
        ]),
        gradient_opacity: Some(vec![(0.0, 0.3), (30.0, 1.0)]),
    };
    let tf = t.p("tf.json");
    spec.save(Path::new(&tf)).unwrap();
    assert_eq!(TfSpec::load(Path::new(&tf)).unwrap(), spec);
    let from_file = render(&[&head64(), "--tf", &tf], &t.p("a.png"));
    let from_options = render(
        &[
            &head64(),
            "--opacity",
            "40:0,90:0.05,200:0.6",
            "--color",
            "40:#904030,220:#fff0e0",
            "--gradient-opacity",
            "0:0.3,30:1",
            "--shading",
        ],
        &t.p("b.png"),
    );
    assert!(from_file == from_options, "--tf differs from the options");
    // Options override the file's parts.
    let overridden = render(
        &[&head64(), "--tf", &tf, "--opacity", "40:0,200:0.2"],
        &t.p("c.png"),
    );
    assert!(overridden != from_file);
    // Normalized units: 0..1 over 0..255 for 8-bit data.
    std::fs::write(
        &tf,
        r##"{"version": 1, "units": "normalized", "shading": true,
             "opacity": [[0.2, 0], [0.8, 0.5]], "color": [[0, "#804020"], [1, "#ffffff"]]}"##,
    )
    .unwrap();
    let normalized = render(&[&head64(), "--tf", &tf], &t.p("d.png"));
    let raw = render(
        &[
            &head64(),
            "--opacity",
            "51:0,204:0.5",
            "--color",
            "0:#804020,255:#ffffff",
            "--shading",
        ],
        &t.p("e.png"),
    );
    assert!(normalized == raw);
}

#[test]
fn presets_equal_their_spelled_out_transfer_functions() {
    let t = Tmp::new("preset");
    let preset = render(&[&head64(), "--preset", "mr-default"], &t.p("a.png"));
    let spelled = render(
        &[
            &head64(),
            "--opacity",
            "0:0,38.25:0,102:0.1,255:0.8",
            "--color",
            "0:#805040,127.5:#e0b090,255:#fffff0",
            "--shading",
        ],
        &t.p("b.png"),
    );
    assert!(preset == spelled);
    let mip = render(&[&head64(), "--preset", "mip"], &t.p("c.png"));
    let spelled = render(
        &[
            &head64(),
            "--mode",
            "mip",
            "--opacity",
            "12.75:0,38.25:1",
            "--color",
            "0:#805040,127.5:#e0b090,255:#fffff0",
        ],
        &t.p("d.png"),
    );
    assert!(mip == spelled);
    // CT presets are in HU: on the shared CT head (sidecar mapping u16 = HU + 1024).
    if let Some(ct) = shared("ct_head.json") {
        let ct = ct.to_string_lossy().into_owned();
        let preset = render(&[&ct, "--u16", "--preset", "ct-bone"], &t.p("e.png"));
        let spelled = render(
            &[
                &ct,
                "--u16",
                "--opacity",
                "1174:0,1324:0.3,2524:0.9",
                "--color",
                "1174:#a06040,1424:#f0e0c0,2524:#ffffff",
                "--shading",
            ],
            &t.p("f.png"),
        );
        assert!(preset == spelled);
        let (code, out, _) = shearwarp(&["info", &ct]);
        assert_eq!(code, 0);
        assert!(
            out.contains("--preset ct-bone") && out.contains("--preset ct-angio"),
            "{out}"
        );
        assert!(!out.contains("mr-default"), "{out}");
    }
}

#[test]
fn window_maps_16_bit_data_onto_the_8_bit_pipeline() {
    let t = Tmp::new("window");
    // A u16 copy of the 64³ head: v16 = 1000 + 4·v8, so the window 1000..2020 (C 1510,
    // W 1020) maps it back onto v8 exactly.
    let v8 = std::fs::read(fixtures().join("mr_head_colin27_64.u8.raw")).unwrap();
    let v16: Vec<u8> = v8
        .iter()
        .flat_map(|&v| (1000 + 4 * v as u16).to_le_bytes())
        .collect();
    std::fs::write(t.p("w.u16.raw"), v16).unwrap();
    std::fs::write(
        t.p("w.json"),
        r#"{"dims_xyz": [64, 64, 64], "spacing_mm_xyz": [2.828125, 3.390625, 2.828125],
            "files": {"u16": {"file": "w.u16.raw", "voxel_type": "u16"}}}"#,
    )
    .unwrap();
    let windowed = render(
        &[
            &t.p("w.json"),
            "--window",
            "1510:1020",
            "--opacity",
            "1160:0,1400:0.1,2020:0.8",
            "--color",
            "1000:#805040,2020:#fffff0",
            "--shading",
        ],
        &t.p("a.png"),
    );
    let eight = render(
        &[
            &head64(),
            "--opacity",
            "40:0,100:0.1,255:0.8",
            "--color",
            "0:#805040,255:#fffff0",
            "--shading",
        ],
        &t.p("b.png"),
    );
    assert!(
        windowed == eight,
        "the window does not reproduce the 8-bit volume"
    );
    // A narrower window clamps: everything above its top is one value.
    let narrow = render(
        &[
            &t.p("w.json"),
            "--window",
            "1300:400",
            "--opacity",
            "1160:0,1400:0.1,2020:0.8",
            "--shading",
        ],
        &t.p("c.png"),
    );
    assert!(narrow != windowed);
    // With an HU mapping the window is in HU: the shared CT head (u16 = HU + 1024) at
    // 400:1800 HU equals the same file without the mapping at 1424:1800 stored.
    if let Some(ct) = shared("ct_head.json") {
        let data = ct.with_file_name("ct_head.u16.raw.gz");
        std::fs::write(
            t.p("plain.json"),
            format!(
                r#"{{"dims_xyz": [256, 256, 108], "spacing_mm_xyz": [0.957031, 0.957031, 1.5],
                    "files": {{"u16": {{"file": "{}", "voxel_type": "u16"}}}}}}"#,
                data.display()
            ),
        )
        .unwrap();
        let opts = ["--opacity", "100:0,140:0.3,255:0.9", "--shading"];
        let mut a = vec![ct.to_str().unwrap(), "--u16", "--window", "400:1800"];
        a.extend_from_slice(&opts);
        let hu = render(&a, &t.p("d.png"));
        let plain = t.p("plain.json");
        let mut b = vec![plain.as_str(), "--window", "1424:1800"];
        b.extend_from_slice(&opts);
        let stored = render(&b, &t.p("e.png"));
        assert!(
            hu == stored,
            "the HU window differs from the stored-value window"
        );
    }
}

#[test]
fn png16_rounds_to_the_8_bit_image() {
    let t = Tmp::new("png16");
    let eight = render(&[&head64(), "--shading"], &t.p("a.png"));
    let (code, _, err) = shearwarp(&[
        "render",
        &head64(),
        "--size",
        "96x96",
        "--rotate-x",
        "-70",
        "--rotate-y",
        "-35",
        "--shading",
        "--png16",
        "-o",
        &t.p("b.png"),
    ]);
    assert_eq!(code, 0, "{err}");
    let img = image::open(t.p("b.png")).unwrap();
    assert_eq!(img.color(), image::ColorType::Rgb16);
    let sixteen = img.to_rgb16().into_raw();
    assert_eq!(sixteen.len(), eight.len());
    let mut finer = 0;
    for (&w, &n) in sixteen.iter().zip(&eight) {
        let r = ((w as u32 * 255 + 32767) / 65535) as u8;
        assert!(r.abs_diff(n) <= 1, "{w} vs {n}");
        finer += (w % 257 != 0) as usize;
    }
    assert!(finer > 100, "no precision beyond 8 bits ({finer} values)");
}

#[test]
fn turntable_writes_gif_apng_and_numbered_pngs() {
    let t = Tmp::new("turn");
    let base = ["render", &head64(), "--size", "48x40", "--turntable", "4"];
    for out in ["t.gif", "t.png", "f%02d.png"] {
        let mut a = base.to_vec();
        let o = t.p(out);
        a.extend_from_slice(&["-o", &o, "--shading"]);
        let (code, _, err) = shearwarp(&a);
        assert_eq!(code, 0, "{out}: {err}");
    }
    use image::AnimationDecoder;
    let gif = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
        std::fs::File::open(t.p("t.gif")).unwrap(),
    ))
    .unwrap();
    let frames = gif.into_frames().collect_frames().unwrap();
    assert_eq!(frames.len(), 4);
    assert_eq!(frames[0].buffer().dimensions(), (48, 40));
    let dec = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(t.p("t.png")).unwrap(),
    ));
    let reader = dec.read_info().unwrap();
    let actl = reader.info().animation_control.unwrap();
    assert_eq!(actl.num_frames, 4);
    // Frame i of the numbered files is the still image at rotate-y 90·i.
    for (i, ry) in [(0, "0"), (1, "90"), (3, "270")] {
        let still = t.p(&format!("still{i}.png"));
        let (code, _, err) = shearwarp(&[
            "render",
            &head64(),
            "--size",
            "48x40",
            "--shading",
            "--rotate-y",
            ry,
            "-o",
            &still,
        ]);
        assert_eq!(code, 0, "{err}");
        let a = image::open(&still).unwrap().to_rgb8();
        let b = image::open(t.p(&format!("f{i:02}.png"))).unwrap().to_rgb8();
        assert!(a == b, "frame {i}");
    }
    assert!(!Path::new(&t.p("f04.png")).exists());
}

#[test]
fn json_and_quiet_output() {
    let t = Tmp::new("json");
    let o = t.p("a.png");
    let (code, out, err) = shearwarp(&["render", &head64(), "--size", "32x32", "-o", &o, "--json"]);
    assert_eq!(code, 0, "{err}");
    assert!(err.is_empty(), "{err}");
    let j: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(j["output"], o.as_str());
    assert_eq!(j["dims_xyz"], serde_json::json!([64, 64, 64]));
    assert!(j["render_ms"].as_f64().unwrap() >= 0.0);
    let (code, out, err) = shearwarp(&[
        "bench",
        &head64(),
        "--size",
        "32x32",
        "--frames",
        "3",
        "--threads",
        "2",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let j: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(j["frames"], 3);
    assert!(j["median_ms"].as_f64().unwrap() >= j["min_ms"].as_f64().unwrap());
    // The phases: one busy time per thread, none longer than the compositing phase.
    let phases = &j["phase_medians_ms"];
    let busy = phases["busy"].as_array().unwrap();
    assert_eq!(busy.len(), 2, "{phases}");
    let composite = phases["composite"].as_f64().unwrap();
    assert!(
        busy.iter().all(|b| b.as_f64().unwrap() <= composite),
        "{phases}"
    );
    let (code, out, _) = shearwarp(&["info", &head64(), "--json"]);
    assert_eq!(code, 0);
    let j: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(j["presets"][0]["name"], "mr-default");
    assert!(j["histogram"].as_array().unwrap().len() > 1);
    for args in [
        vec!["render", &head64(), "--size", "32x32", "-o", &o, "--quiet"],
        vec!["bench", &head64(), "--size", "32x32", "--frames", "2", "-q"],
        vec!["info", &head64(), "--quiet"],
    ] {
        let (code, out, err) = shearwarp(&args);
        assert_eq!(code, 0, "{args:?}");
        assert!(out.is_empty() && err.is_empty(), "{args:?}: {out} {err}");
    }
    // Not a terminal: no progress bars on stderr.
    let (_, _, err) = shearwarp(&["render", &head64(), "--size", "32x32", "-o", &o]);
    assert_eq!(err.lines().count(), 1, "{err}");
}

/// `--flat-voxels auto` (the default) excludes flat voxels from samples' colours in a
/// volume of plateaus and blends them in scanned data, and renders as the way it picks.
#[test]
fn flat_voxels_follow_the_volume_by_default() {
    let t = Tmp::new("flat");
    // A ball of one value: its inside has no gradient.
    let n = 32usize;
    let c = (n as f64 - 1.0) / 2.0;
    let ball: Vec<u8> = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (i % n, i / n % n, i / (n * n));
            let d2 = [x, y, z]
                .map(|v| (v as f64 - c).powi(2))
                .iter()
                .sum::<f64>();
            if d2 < 100.0 {
                200
            } else {
                0
            }
        })
        .collect();
    std::fs::write(t.p("ball.u8.raw"), ball).unwrap();
    std::fs::write(
        t.p("ball.json"),
        r#"{"dims_xyz": [32, 32, 32], "spacing_mm_xyz": [1, 1, 1],
            "files": {"u8": {"file": "ball.u8.raw", "voxel_type": "u8"}}}"#,
    )
    .unwrap();
    let way = |vol: &str, extra: &[&str]| {
        let mut a = vec!["bench", vol, "--size", "32x32", "--frames", "1", "--json"];
        a.extend_from_slice(extra);
        let (code, out, err) = shearwarp(&a);
        assert_eq!(code, 0, "{a:?}: {err}");
        let j: serde_json::Value = serde_json::from_str(&out).unwrap();
        j["flat_voxels"].as_str().unwrap().to_string()
    };
    let ball = t.p("ball.json");
    assert_eq!(way(&ball, &[]), "excluded");
    assert_eq!(way(&ball, &["--flat-voxels", "blended"]), "blended");
    assert_eq!(way(&head64(), &[]), "blended");
    assert_eq!(way(&head64(), &["--flat-voxels", "excluded"]), "excluded");
    let look = [ball.as_str(), "--shading", "--opacity", "0:0,200:0.5"];
    let img = |way: &str, out: &str| {
        let mut a = look.to_vec();
        a.extend_from_slice(&["--flat-voxels", way]);
        render(&a, &t.p(out))
    };
    let auto = img("auto", "auto.png");
    assert_eq!(auto, img("excluded", "excluded.png"));
    assert_ne!(auto, img("blended", "blended.png"));
}

/// Bad input of every kind the CLI adds: exit code 2, one line naming the file (or the
/// option) and the problem.
#[test]
fn bad_inputs_exit_2_with_one_line() {
    let t = Tmp::new("bad");
    let o = t.p("o.png");
    let mut cases: Vec<(Vec<String>, String)> = Vec::new();
    let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    // Dims over a configurable limit (the fixture has 262144 voxels).
    cases.push((
        s(&["render", &head64(), "-o", &o, "--max-voxels", "100000"]),
        "more than 100000 voxels".into(),
    ));
    cases.push((
        s(&["info", &head64(), "--max-voxels", "100000"]),
        "mr_head_colin27_64.json: unusable dims_xyz".into(),
    ));
    cases.push((
        s(&["render", &head64(), "-o", &o, "--isa", "x86-64-v9"]),
        "unknown instruction-set level \"x86-64-v9\"".into(),
    ));
    // Unknown preset; a CT preset on data without HU.
    cases.push((
        s(&["render", &head64(), "-o", &o, "--preset", "ct-lung"]),
        "invalid value 'ct-lung'".into(),
    ));
    cases.push((
        s(&["render", &head64(), "-o", &o, "--preset", "ct-bone"]),
        "mr_head_colin27_64.json: the transfer function is in Hounsfield units".into(),
    ));
    // Bad TF files.
    for (i, (text, want)) in [
        ("{not json", "invalid JSON"),
        (r#"{"opacity": [[0, 0]]}"#, "\"version\": missing"),
        (
            r#"{"version": 2, "opacity": [[0, 0]]}"#,
            "\"version\": unsupported version 2",
        ),
        (
            r#"{"version": 1, "opacity": [[0, 0], [10, 1.5]]}"#,
            "\"opacity\"[1]: 1.5 is not a number in 0..1",
        ),
        (
            r#"{"version": 1, "opacity": [[5, 0], [5, 1]]}"#,
            "\"opacity\"[1]: value 5 is not greater",
        ),
        (
            r#"{"version": 1, "opacity": [[0, 0]], "colour": []}"#,
            "\"colour\": unknown field",
        ),
        (
            r#"{"version": 1, "opacity": [[0, 0]], "color": [[0, "red"]]}"#,
            "\"color\"[0]: \"red\" is not a colour",
        ),
        (
            r#"{"version": 1, "units": "hu", "opacity": [[0, 0]]}"#,
            "the transfer function is in Hounsfield units",
        ),
        (r#"{"version": 1}"#, "\"opacity\": missing"),
    ]
    .iter()
    .enumerate()
    {
        let f = t.p(&format!("tf{i}.json"));
        std::fs::write(&f, text).unwrap();
        let name = if want.contains("Hounsfield") {
            "mr_head_colin27_64.json".to_string()
        } else {
            format!("tf{i}.json")
        };
        cases.push((
            s(&["render", &head64(), "-o", &o, "--tf", &f]),
            format!("{name}: {want}"),
        ));
    }
    cases.push((
        s(&["render", &head64(), "-o", &o, "--tf", &t.p("absent.json")]),
        "absent.json: cannot read".into(),
    ));
    // Bad --window, --turntable output.
    cases.push((
        s(&["render", &head64(), "-o", &o, "--window", "40"]),
        "--window '40'".into(),
    ));
    cases.push((
        s(&["render", &head64(), "-o", &o, "--window", "40:-5"]),
        "--window '40:-5'".into(),
    ));
    cases.push((
        s(&["render", &head64(), "-o", &t.p("x.jpg"), "--turntable", "3"]),
        "x.jpg: --turntable writes".into(),
    ));
    cases.push((
        s(&[
            "render",
            &head64(),
            "-o",
            &t.p("x.gif"),
            "--turntable",
            "3",
            "--png16",
        ]),
        "x.gif: a GIF holds 8-bit colour only".into(),
    ));
    // Option values only the core's checks refuse.
    cases.push((
        s(&["render", &head64(), "-o", &o, "--supersample", "9"]),
        "supersampling factor must be 1..=4".into(),
    ));
    cases.push((
        s(&["render", &head64(), "-o", &o, "--ert", "2"]),
        "early-ray-termination threshold".into(),
    ));
    // A truncated `.swv` file, and one whose colour table was overwritten.
    let swv = t.p("whole.swv");
    let (code, _, err) = shearwarp(&["encode", &head64(), "-o", &swv, "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let whole = std::fs::read(&swv).unwrap();
    // Cut inside the slice table, and inside the slices (which the table points past).
    for (name, len, want) in [
        ("cut1.swv", 5000, "input ends early (truncated)"),
        (
            "cut2.swv",
            whole.len() / 3,
            "invalid .swv volume: slice counts exceed what the slice or the file can hold",
        ),
    ] {
        let cut = t.p(name);
        std::fs::write(&cut, &whole[..len]).unwrap();
        cases.push((s(&["render", &cut, "-o", &o]), format!("{name}: {want}")));
    }
    let mut bad = whole.clone();
    bad[200..260].fill(0xff);
    let corrupt = t.p("corrupt.swv");
    std::fs::write(&corrupt, &bad).unwrap();
    cases.push((
        s(&["render", &corrupt, "-o", &o]),
        "corrupt.swv: invalid .swv volume".into(),
    ));
    // Bad crop boxes, and boxes or levels where they cannot apply.
    for (extra, want) in [
        (
            &[":10"][..],
            "--crop ':10': expected three ranges X0:X1,Y0:Y1,Z0:Z1",
        ),
        (&["5:2,,"], "--crop '5:2,,': x range 5:2 is empty"),
        (
            &[",0:64,"],
            "--crop ',0:64,': y bound 64 is outside the volume (0..=63)",
        ),
        (&[",,a:"], "--crop ',,a:': 'a' is not a voxel index"),
        (
            &[",,70:"],
            "--crop ',,70:': z bound 70 is outside the volume (0..=63)",
        ),
        (&[",12,"], "--crop ',12,': range '12' is not LO:HI"),
        (
            &["3:3,,", "--lod", "2"],
            "--crop '3:3,,': holds no voxel of --lod 2",
        ),
        (
            &[",,", "--mode", "post", "--lod", "1"],
            "--lod renders the classified volume",
        ),
    ] {
        let mut a = s(&["render", &head64(), "-o", &o, "--crop"]);
        a.extend(s(extra));
        cases.push((a, want.into()));
    }
    // Bad clipping planes.
    for (extra, want) in [
        (
            &["1,0"][..],
            "--clip '1,0': expected a normal NX,NY,NZ and an optional :OFFSET",
        ),
        (&["0,0,0"], "--clip '0,0,0': the normal is zero"),
        (&["1,x,0"], "--clip '1,x,0': 'x' is not a number"),
        (&["1,0,0:2"], "--clip '1,0,0:2': offset 2 is outside -1..=1"),
        (&["1,0,0:nan"], "--clip '1,0,0:nan': 'nan' is not a number"),
        (
            &[
                "1,0,0", "--clip", "1,0,0", "--clip", "1,0,0", "--clip", "1,0,0", "--clip",
                "1,0,0", "--clip", "1,0,0", "--clip", "1,0,0",
            ],
            "--clip: at most 6 planes",
        ),
    ] {
        let mut a = s(&["render", &head64(), "-o", &o, "--clip"]);
        a.extend(s(extra));
        cases.push((a, want.into()));
    }
    cases.push((
        s(&["render", &head64(), "-o", &o, "--clip-invert"]),
        "--clip-invert needs at least one --clip plane".into(),
    ));
    cases.push((
        s(&["render", &head64(), "-o", &o, "--clip-live"]),
        "the following required arguments were not provided: --clip".into(),
    ));
    cases.push((
        s(&["render", &head64(), "-o", &o, "--clip-face", "2"]),
        "the following required arguments were not provided: --clip".into(),
    ));
    cases.push((
        s(&[
            "render",
            &head64(),
            "-o",
            &o,
            "--clip",
            "1,0,0",
            "--clip-face",
            "17",
        ]),
        "--clip-face 17: the face's thickness is 0 to 16 voxels".into(),
    ));
    cases.push((
        s(&[
            "encode",
            &head64(),
            "-o",
            &o,
            "--clip",
            "1,0,0",
            "--clip-live",
        ]),
        "encode bakes --clip planes into a raw volume's encoding".into(),
    ));
    cases.push((
        s(&["render", &swv, "-o", &o, "--crop", ":31,,"]),
        "whole.swv: opacity is baked into a .swv file".into(),
    ));
    // Inconsistent DICOM slice sizes (Rows patched in one file of the shared series).
    if let Some(dir) = shared("dicom/mr_pd_brain_series") {
        let d = t.p("inconsistent");
        std::fs::create_dir_all(&d).unwrap();
        for i in [2, 3, 4] {
            let n = format!("brain_{i:03}.dcm");
            let mut b = std::fs::read(dir.join(&n)).unwrap();
            if i == 3 {
                let rows = [0x28, 0, 0x10, 0, b'U', b'S', 2, 0];
                let at = b.windows(8).position(|w| w == rows).unwrap() + 8;
                b[at..at + 2].copy_from_slice(&128u16.to_le_bytes());
            }
            std::fs::write(Path::new(&d).join(&n), b).unwrap();
        }
        cases.push((
            s(&["render", &d, "-o", &o]),
            "brain_003.dcm: inconsistent slice sizes: 256×128 here, 256×256".into(),
        ));
    }
    for (args, want) in &cases {
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        let (code, _, err) = shearwarp(&a);
        assert_eq!(code, 2, "{a:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{a:?}: {err}");
        assert!(err.starts_with("error: "), "{err}");
        assert!(
            err.contains(want.as_str()),
            "{a:?}: want {want:?}, got {err}"
        );
    }
}

/// Failing to write the output is not bad input: exit code 1, one line naming the file.
#[test]
fn an_unwritable_output_exits_1() {
    let t = Tmp::new("unwritable");
    let missing = t.p("no/such/dir");
    for (cmd, name) in [("render", "x.png"), ("encode", "x.swv")] {
        let out = format!("{missing}/{name}");
        let (code, _, err) = shearwarp(&[cmd, &head64(), "-o", &out]);
        assert_eq!(code, 1, "{cmd}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.starts_with("error: ") && err.contains(name), "{err}");
    }
}
