//! `lfr demo`: the product in one command on the embedded default scene (the Cornell box), no
//! file needed. It is `lfr compare` with fixed arguments, printed before the run so that the
//! user can rerun or change them: indirect light at 128 × 128, inputs of 1, 4 and 16 samples per
//! pixel (OIDN runs on every rung of path tracing's ladder as well), the indirect light field
//! reconstruction (`ilfr`, its default, the sparse gather, at 16 reconstruction rays: against
//! path tracing as fast to its quality as at 64 rays, 8.6–9.0× against 8.0–8.6×, in half the time),
//! the same fed to the denoiser (`ilfr+oidn`) and the denoiser alone (`oidn`), path tracing up to
//! 64 spp, against a 2048-spp reference (its own PSNR about 43 dB, 6 dB above the best run). About
//! 75 s on 2 cores with the reference, 30 s once it is cached. It writes `report.html` (headline, verdicts, error-against-time plot,
//! split-screen viewer) and prints what won at each time budget and where the report is.

use std::path::PathBuf;

use anyhow::Result;
use clap::Parser;

use crate::compare::{self, CompareArgs};

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Output directory of the comparison (a previous comparison there is replaced).
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Reference cache (default: as `lfr compare`).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// The `lfr compare` arguments the demo runs, after `lfr compare`.
pub fn compare_arguments(args: &DemoArgs) -> Vec<String> {
    let mut list: Vec<String> = [
        "--effect",
        "indirect",
        "--width",
        "128",
        "--height",
        "128",
        "--spp",
        "1,4,16",
        "--recon-rays",
        "16",
        "--methods",
        "ilfr,ilfr+oidn,oidn",
        "--reference-spp",
        "2048",
        "--pt-max-spp",
        "64",
        "--repeats",
        "3",
        "--out",
    ]
    .map(String::from)
    .to_vec();
    list.push(args.out.display().to_string());
    if let Some(cache) = &args.cache_dir {
        list.extend(["--cache-dir".to_string(), cache.display().to_string()]);
    }
    if let Some(threads) = args.threads {
        list.extend(["--threads".to_string(), threads.to_string()]);
    }
    list
}

/// `lfr compare`'s arguments parsed as the command line would parse them.
#[derive(Parser)]
struct CompareCommand {
    #[command(flatten)]
    compare: CompareArgs,
}

pub fn run(args: &DemoArgs) -> Result<()> {
    let arguments = compare_arguments(args);
    eprintln!("demo: lfr compare {}", arguments.join(" "));
    let command = CompareCommand::try_parse_from(std::iter::once("lfr compare".to_string()).chain(arguments))
        .map_err(|e| anyhow::anyhow!("demo: the compare arguments do not parse: {e}"))?;
    compare::run(&command.compare)?;
    println!(
        "open {} in a browser: the verdict, the error-against-time plot and the images",
        args.out.join("report.html").display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The demo's arguments are valid `lfr compare` arguments (a second parser: clap's), and the
    /// output folder and optional settings pass through.
    #[test]
    fn the_demo_arguments_parse_as_lfr_compare_arguments() {
        let args = DemoArgs { out: PathBuf::from("x/y"), cache_dir: Some(PathBuf::from("c")), threads: Some(2) };
        let command =
            CompareCommand::try_parse_from(std::iter::once("lfr compare".to_string()).chain(compare_arguments(&args)))
                .unwrap();
        let compare = command.compare;
        assert_eq!(compare.out, Some(PathBuf::from("x/y")));
        assert_eq!(compare.cache_dir, Some(PathBuf::from("c")));
        assert_eq!(compare.spp, vec![1, 4, 16]);
        assert_eq!(compare.recon_rays, Some(vec![16]));
        assert_eq!(compare.methods, vec!["ilfr", "ilfr+oidn", "oidn"]);
        assert!(compare.trace.scene.is_none(), "the embedded default scene");
    }
}
