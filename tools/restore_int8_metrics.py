"""Re-measure the int8 models' own rows (after a re-quantisation), keeping their stored ICP-60 row.

For every ``sdk/models/*.int8.onnx``: ``equipose eval --model M --icp-templates 0`` on the test set named in its stored
metrics; the new row replaces the stored one (ICP-60's row and sample count are kept: they do not depend on the file).
Usage: python tools/restore_int8_metrics.py [NAME ...]   (prints old → new)
"""
import json
import pathlib
import subprocess
import sys
import tempfile

from equipose.export.onnx_export import update_metadata
from equipose.metadata import decode_metadata
from equipose.train.metrics import ROW_KEYS


def props(path) -> dict:
    import onnx
    return {p.key: p.value for p in onnx.load(str(path)).metadata_props}


def main(names) -> int:
    for q in sorted(pathlib.Path("sdk/models").glob("*.int8.onnx")):
        if names and q.name.split(".")[0] not in names:
            continue
        old = decode_metadata(props(q), source=q.name)["metrics"]
        cat, mode = old["test_set"].split(" ")[0].split("/")
        refine = (decode_metadata(props(q), source=q.name).get("refine_calibration") or {}).get("k", 0)
        with tempfile.TemporaryDirectory() as tmp:
            js = pathlib.Path(tmp) / "r.json"
            subprocess.run([str(pathlib.Path(sys.executable).with_name("equipose")), "eval", "--model", str(q), "--category", cat, "--mode", mode,
                            "--icp-templates", "0", "--json", str(js)], check=True, capture_output=True)
            rows = json.loads(js.read_text())["rows"]
        row = rows[0]
        new = dict(old)
        for k in ROW_KEYS[1:]:
            new[k] = round(float(row[k]), 4)
        new["method"] = row["method"]
        update_metadata(q, metrics=new)
        print(f"{q.name} (refine {refine}): {old['rot_mean_deg']:.2f}/{old['rot_median_deg']:.2f}/{old['acc_5deg']:.2f} → "
              f"{new['rot_mean_deg']:.2f}/{new['rot_median_deg']:.2f}/{new['acc_5deg']:.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
