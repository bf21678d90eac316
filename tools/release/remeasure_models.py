"""Re-measure the shipped models' stored test metrics with the current SDK (after a change on the prediction path).

For every ``sdk/models/NAME[.int8].onnx`` (or the NAMEs given): the two evaluation steps of a release
(``python -m equipose.train.release NAME``) again — the plain network (``--refine 0``, no ICP-60) into
``docs/results/models/F.norefine.txt`` when the file has a refined calibration, then the file's own setting with ICP-60
on the same number of test samples as before, ``--store-metrics``, JSON, plot and text into
``docs/results/models/F.{json,png,txt}``. Test set (category / mode) and ICP sample count are read from the file's
stored metrics. Prints old → new rotation mean / median / 5°.

Usage: python tools/release/remeasure_models.py [NAME | FILE.onnx ...]   (NAME: fp32 and int8; FILE: that file only)
"""
import pathlib
import subprocess
import sys

from equipose.core.metadata import decode_metadata

OUT = pathlib.Path("docs/results/models")
EQ = str(pathlib.Path(sys.executable).with_name("equipose"))


def meta(path) -> dict:
    import onnx
    return decode_metadata({p.key: p.value for p in onnx.load(str(path)).metadata_props}, source=path.name)


def main(names) -> int:
    from equipose.models import list_models                      # the int8 copies built from their fp32 files
    files = [p.relative_to(pathlib.Path.cwd()) if p.is_relative_to(pathlib.Path.cwd()) else p for p in list_models()]
    for f in files:
        stem = f.name[:-len(".onnx")]
        if names and stem.split(".")[0] not in names and f.name not in names:          # NAME, or FILE.onnx exactly
            continue
        m = meta(f)
        old = m["metrics"]
        cat, mode = old["test_set"].split(" ")[0].split("/")
        base = [EQ, "eval", "--model", str(f), "--category", cat, "--mode", mode]
        if m.get("refine_calibration"):
            txt = subprocess.run(base + ["--refine", "0", "--icp-templates", "0"], check=True, capture_output=True,
                                 text=True).stdout
            (OUT / f"{stem}.norefine.txt").write_text(txt)
        txt = subprocess.run(base + ["--icp-samples", str(old["icp60_samples"]), "--json", str(OUT / f"{stem}.json"),
                                     "--plot", str(OUT / f"{stem}.png"), "--store-metrics"],
                             check=True, capture_output=True, text=True).stdout
        (OUT / f"{stem}.txt").write_text(txt)
        new = meta(f)["metrics"]
        fmt = "{rot_mean_deg:.2f}/{rot_median_deg:.2f}/{acc_5deg:.2f}"
        print(f"{f.name}: {fmt.format(**old)} → {fmt.format(**new)};  ICP-60 {fmt.format(**old['icp60'])} → "
              f"{fmt.format(**new['icp60'])}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
