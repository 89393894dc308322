//! Argument parsing (clap derive) and dispatch. Each subcommand has its own module with its
//! arguments struct and a `run` function, so subcommands can be developed independently.
//! Value parsers shared by several subcommands are here, so limits and messages agree.

pub mod bake;
pub mod bench;
pub mod demo;
pub mod eval;
pub mod probe;
pub mod render;
pub mod synth;

use clap::{Parser, Subcommand, ValueEnum};
use surfsynth::error::one_line;
use surfsynth::io::exr::{Compression, MAX_RESOLUTION};

/// Texture synthesis directly on Catmull-Clark subdivision surfaces.
#[derive(Parser, Debug)]
#[command(name = "surfsynth", version, about, max_term_width = 100)]
pub struct Cli {
    /// Worker threads (default: all cores, or RAYON_NUM_THREADS). Results do not depend on it.
    #[arg(long, global = true, value_name = "T", value_parser = parse_threads, allow_negative_numbers = true)]
    pub threads: Option<usize>,

    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Synthesize a texture from an example image over a subdivision surface.
    // Boxed: its flags are many times the size of the other commands'.
    Synth(Box<synth::SynthArgs>),
    /// Write only the geometry maps (limit position and normal per texel).
    Bake(bake::BakeArgs),
    /// Print the sampling pattern around a surface point as JSON (sampler validation).
    Probe(probe::ProbeArgs),
    /// Render a preview picture of a synthesis result.
    Render(render::RenderArgs),
    /// Print quality measures of a synthesis result as JSON.
    Eval(eval::EvalArgs),
    /// Run the full pipeline on the bundled mesh and example.
    Demo(demo::DemoArgs),
    /// Performance benchmarks.
    Bench(bench::BenchArgs),
}

/// Parses arguments, runs the subcommand and returns the exit code. Errors are printed as
/// exactly one line.
pub fn main() -> i32 {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => return usage_error(e),
    };
    let r = run(cli);
    // A signal arrived: its thread removes what is partial, prints the one line and picks
    // the exit code (an error seen meanwhile is a consequence of the interruption).
    if surfsynth::io::interrupt::interrupted().is_some() {
        surfsynth::io::interrupt::wait_for_exit();
    }
    match r {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("error: {}", one_line(&format!("{e:#}")));
            if e.downcast_ref::<Usage>().is_some() {
                2
            } else {
                1
            }
        }
    }
}

/// A usage error found after parsing: flags that parse one by one but do not go together
/// (`--search` without `--method multiscale`). Exit code 2, like clap's own.
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// `Err(Usage(msg))` as an anyhow error.
pub fn usage<T>(msg: impl Into<String>) -> anyhow::Result<T> {
    Err(Usage(msg.into()).into())
}

fn run(cli: Cli) -> anyhow::Result<()> {
    if let Some(t) = cli.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()
            .map_err(|e| anyhow::anyhow!("cannot start {t} worker threads: {e}"))?;
    }
    // Test hook for the "no panic text, ever" contract (tests/bad_inputs.rs): a panic on
    // a worker thread, the hardest case for the hook in main.rs.
    if std::env::var_os("SURFSYNTH_INJECT_PANIC").is_some() {
        use rayon::prelude::*;
        (0..64).into_par_iter().for_each(|i| {
            if i % 7 == 3 {
                panic!("injected panic {i}\nwith a second line");
            }
        });
    }
    match cli.command {
        Command::Synth(a) => synth::run(*a),
        Command::Bake(a) => bake::run(a),
        Command::Probe(a) => probe::run(a),
        Command::Render(a) => render::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Bench(a) => bench::run(a),
    }
}

/// Help and version go to stdout as clap formats them; real usage errors become one line
/// (clap's first paragraph, e.g. "error: unexpected argument '--foo' found"), exit code 2.
fn usage_error(e: clap::Error) -> i32 {
    use clap::error::ErrorKind;
    match e.kind() {
        ErrorKind::DisplayHelp | ErrorKind::DisplayVersion => {
            let _ = e.print();
            0
        }
        ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => {
            let _ = e.print();
            2
        }
        _ => {
            let text = e.render().to_string();
            let first = text.split("\n\n").next().unwrap_or("").trim();
            let line = one_line(first);
            if line.starts_with("error:") {
                eprintln!("{line}");
            } else {
                eprintln!("error: {line}");
            }
            2
        }
    }
}

/// `--resolution`: 1..=8192 texels per face side.
pub fn parse_resolution(s: &str) -> Result<usize, String> {
    let n: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a whole number of texels"))?;
    if n == 0 {
        return Err("resolution must be at least 1 texel per side".into());
    }
    if n > MAX_RESOLUTION {
        return Err(format!(
            "resolution {n} is too large: at most {MAX_RESOLUTION} texels per side are supported"
        ));
    }
    Ok(n)
}

/// `--threads`: 1..=1024.
pub fn parse_threads(s: &str) -> Result<usize, String> {
    let t: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a whole number of threads"))?;
    if !(1..=1024).contains(&t) {
        return Err(format!("{t} threads: must be between 1 and 1024"));
    }
    Ok(t)
}

/// A finite number > 0 (scales, steps).
pub fn parse_positive(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() || v <= 0.0 {
        return Err(format!("{s} must be a finite number greater than 0"));
    }
    Ok(v)
}

/// Any finite number (angles, displacement amounts, coordinates).
pub fn parse_finite(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() {
        return Err(format!("{s} must be a finite number"));
    }
    Ok(v)
}

/// Image size in pixels: 1..=16384.
pub fn parse_pixels(s: &str) -> Result<u32, String> {
    let v: u32 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a whole number of pixels"))?;
    if !(1..=16384).contains(&v) {
        return Err(format!("{v} pixels: must be between 1 and 16384"));
    }
    Ok(v)
}

/// `--orient`: `auto`, `straight`, an axis `+x|-x|+y|-y|+z|-z` (a bare `x` means `+x`), or the path of
/// an existing constraints file.
pub fn parse_orient(s: &str) -> Result<surfsynth::field::Orientation, String> {
    use glam::DVec3;
    use surfsynth::field::Orientation;
    let axis = |c: &str| match c {
        "x" => Some(DVec3::X),
        "y" => Some(DVec3::Y),
        "z" => Some(DVec3::Z),
        _ => None,
    };
    let t = s.trim();
    let lower = t.to_ascii_lowercase();
    if lower == "auto" {
        return Ok(Orientation::Auto);
    }
    if lower == "straight" {
        return Ok(Orientation::Straight);
    }
    let (up, upright) = match lower.strip_prefix("upright") {
        Some(rest) => (Some(rest), true),
        None => (lower.strip_prefix("up"), false),
    };
    if let Some(up) = up {
        let (sign, rest) = match up.as_bytes().first() {
            Some(b'+') => (1.0, &up[1..]),
            Some(b'-') => (-1.0, &up[1..]),
            _ => (1.0, up),
        };
        match axis(if rest.is_empty() { "y" } else { rest }) {
            Some(a) if upright => return Ok(Orientation::Upright(a * sign)),
            Some(a) => return Ok(Orientation::Up(a * sign)),
            None if !std::path::Path::new(t).is_file() => {
                let word = if upright { "upright" } else { "up" };
                return Err(format!(
                    "'{s}' is not {word}, {word}+x, {word}-x, {word}+y, {word}-y, {word}+z or {word}-z"
                ));
            }
            None => {}
        }
    }
    let (sign, rest) = match lower.as_bytes().first() {
        Some(b'+') => (1.0, &lower[1..]),
        Some(b'-') => (-1.0, &lower[1..]),
        _ => (1.0, lower.as_str()),
    };
    if let Some(a) = axis(rest) {
        return Ok(Orientation::Axis(a * sign));
    }
    let p = std::path::Path::new(t);
    if p.is_file() {
        return Ok(Orientation::Constraints(p.to_path_buf()));
    }
    Err(format!(
        "'{s}' is not auto, straight, up[+-axis], upright[+-axis], +x, -x, +y, -y, +z, -z or an existing constraints file"
    ))
}

/// EXR compression choices exposed on the command line (lossless only).
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExrCompression {
    /// No compression: fastest to write (the default; see docs/formats.md).
    None,
    /// Run-length: cheap, only helps on flat regions.
    Rle,
    /// Deflate per 16-line block (per tile here): 25-40% smaller, 3-7x slower to write.
    Zip,
    /// Deflate per scan line.
    Zips,
    /// Wavelet + Huffman: good ratios on noisy data, slower.
    Piz,
}

impl ExrCompression {
    pub fn to_exr(self) -> Compression {
        match self {
            ExrCompression::None => Compression::Uncompressed,
            ExrCompression::Rle => Compression::RLE,
            ExrCompression::Zip => Compression::ZIP16,
            ExrCompression::Zips => Compression::ZIP1,
            ExrCompression::Piz => Compression::PIZ,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn cli_definition_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn parsers_reject_bad_values() {
        assert_eq!(parse_resolution("32"), Ok(32));
        assert!(parse_resolution("0").unwrap_err().contains("at least 1"));
        assert!(parse_resolution("9000").unwrap_err().contains("too large"));
        assert!(parse_resolution("x").is_err());
        assert!(parse_positive("0").is_err());
        assert!(parse_positive("-1").is_err());
        assert!(parse_positive("nan").is_err());
        assert!(parse_positive("inf").is_err());
        assert_eq!(parse_positive("0.5"), Ok(0.5));
        assert!(parse_threads("0").is_err());
        assert!(parse_pixels("0").is_err());
    }

    #[test]
    fn brief_command_lines_parse() {
        let ok = [
            "surfsynth synth --mesh m.obj --example e.png --height h.png --method multiscale --resolution 16 --scale 0.01 --orient -x --seed 3 --threads 2 --out d",
            "surfsynth synth --mesh m.obj --example e.png --orient +z --out d",
            "surfsynth bake --mesh m.obj --resolution 8 --out d",
            "surfsynth probe --mesh m.obj --face 3 --uv 0.5 0.25 --step 0.01 --size 5 --sampler march",
            "surfsynth render d --out p.png --width 640 --height 480",
            "surfsynth render d --light -1,0.5,-2 --pitch -20 --yaw -30",
            "surfsynth eval d --scale 0.5",
            "surfsynth demo --out d",
            "surfsynth demo",
            "surfsynth bench bake --resolution 8",
        ];
        for line in ok {
            let args: Vec<&str> = line.split_whitespace().collect();
            if let Err(e) = Cli::try_parse_from(&args) {
                panic!("{line}: {e}");
            }
        }
        let bad = [
            "surfsynth bake --mesh m.obj --resolution 0 --out d",
            "surfsynth bake --mesh m.obj --resolution 100000 --out d",
            "surfsynth bake --mesh m.obj --out d --bogus",
            "surfsynth synth --mesh m.obj --example e.png --orient sideways --out d",
            "surfsynth synth --mesh m.obj --example e.png --scale -1 --out d",
            "surfsynth probe --mesh m.obj --face 0 --uv 0.5 --step 0.1",
            "surfsynth probe --mesh m.obj --face 0 --uv 0.5 0.5 --step 0.1 --size 4",
        ];
        for line in bad {
            let args: Vec<&str> = line.split_whitespace().collect();
            assert!(Cli::try_parse_from(&args).is_err(), "{line}");
        }
    }

    #[test]
    fn light_directions_may_be_negative() {
        let cli =
            Cli::try_parse_from(["surfsynth", "render", "d", "--light", "-1,0.5,-2"]).unwrap();
        let Command::Render(a) = cli.command else {
            panic!("not render")
        };
        assert_eq!(a.light, Some(vec![-1.0, 0.5, -2.0]));
    }

    #[test]
    fn orient_values_parse_to_their_fields() {
        use glam::DVec3;
        use surfsynth::field::Orientation as O;
        for (text, want) in [
            ("up", O::Up(DVec3::Y)),
            ("UP+Z", O::Up(DVec3::Z)),
            ("up-x", O::Up(DVec3::NEG_X)),
            ("upright", O::Upright(DVec3::Y)),
            ("Upright-z", O::Upright(DVec3::NEG_Z)),
            ("-y", O::Axis(DVec3::NEG_Y)),
            ("auto", O::Auto),
            ("straight", O::Straight),
        ] {
            assert_eq!(parse_orient(text).unwrap(), want, "{text}");
        }
        let e = parse_orient("up+w").unwrap_err();
        assert!(e.contains("up+x"), "{e}");
        let e = parse_orient("upright+w").unwrap_err();
        assert!(e.contains("upright+x"), "{e}");
    }
}
