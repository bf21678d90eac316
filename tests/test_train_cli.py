"""``equipose train``'s flags come from ``TrainConfig``: one flag per field, the same names as before, parsed into
the config."""
import argparse
import dataclasses
import json
import subprocess
import sys

import pytest

from equipose.commands.train import add_arguments, add_config_arguments, config_flag
from equipose.train.fitting.config import TrainConfig

# every flag the hand-written parser had (and the docs use)
OLD_FLAGS = ["--category", "--mode", "--preset", "--steps", "--out", "--config", "--resume", "--batch-size", "--lr",
             "--data-root", "--val-every", "--ckpt-every", "--val-size", "--train-limit", "--views", "--cache-dir",
             "--threads", "--seed", "--device", "--freeze", "--teacher", "--teacher-refine", "--teacher-priors",
             "--teacher-flip", "--select-weight", "--shape-weight", "--view-weight", "--cloud-weight",
             "--drift-weight", "--drift-iters", "--rotate-augment", "--symmetry-weight", "--minutes", "--init"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="equipose train")
    add_arguments(p)
    return p


def _config(argv, config_file=None) -> TrainConfig:
    args = _parser().parse_args(argv)
    opts = {k: v for k, v in vars(args).items() if k not in ("config", "resume")}
    return TrainConfig.from_sources(config_file or args.config, **opts)


def test_every_field_is_a_flag_and_every_old_flag_still_exists():
    flags = {s for a in _parser()._actions for s in a.option_strings}
    fields = [f.name for f in dataclasses.fields(TrainConfig)]
    assert {config_flag(n) for n in fields} <= flags
    assert set(OLD_FLAGS) <= flags
    assert config_flag("batch_size") == "--batch-size" and "--lr-gamma" in flags and "--no-rotate-augment" in flags
    helps = {a.dest: a.help for a in _parser()._actions}
    assert all(helps[n] for n in fields)
    assert "(default 8)" in helps["batch_size"] and "edge" in helps["preset"] and "{" not in helps["preset"]


def test_flags_parse_into_the_config():
    cfg = _config(["--category", "car", "--mode", "partial", "--batch-size", "4", "--lr", "2e-4", "--view-weight", "3",
                   "--teacher", "t.pt", "--rotate-augment", "--train-limit", "5", "--out", "runs/x", "--steps", "7",
                   "--lr-gamma", "0.99", "--resume"])
    assert (cfg.category, cfg.mode, cfg.batch_size, cfg.lr, cfg.view_weight) == ("car", "partial", 4, 2e-4, 3.0)
    assert (cfg.teacher, cfg.rotate_augment, cfg.train_limit, cfg.out, cfg.steps) == ("t.pt", True, 5, "runs/x", 7)
    assert cfg.lr_gamma == 0.99 and isinstance(cfg.batch_size, int) and isinstance(cfg.view_weight, float)
    default = TrainConfig()
    assert (cfg.preset, cfg.views, cfg.cloud_weight) == (default.preset, default.views, default.cloud_weight)
    assert _config([]) == default


def test_flags_override_the_config_file_and_absent_flags_keep_it(tmp_path):
    f = tmp_path / "config.json"
    f.write_text(json.dumps({"category": "sofa", "mode": "partial", "teacher": "t.pt", "view_weight": 3.0,
                             "rotate_augment": True, "steps": 100}))
    cfg = _config(["--steps", "200", "--no-rotate-augment"], config_file=f)
    assert (cfg.category, cfg.view_weight, cfg.steps, cfg.rotate_augment) == ("sofa", 3.0, 200, False)


def test_bad_values_are_refused():
    with pytest.raises(SystemExit):
        _parser().parse_args(["--mode", "sideways"])
    with pytest.raises(SystemExit):
        _parser().parse_args(["--batch-size", "four"])


def test_a_new_field_gets_its_flag():
    @dataclasses.dataclass
    class Extended(TrainConfig):
        warmup_steps: int = dataclasses.field(default=0, metadata={"help": "steps of linear learning-rate warm-up"})
        note: str | None = None

    p = argparse.ArgumentParser()
    add_config_arguments(p, Extended)
    args = p.parse_args(["--warmup-steps", "50", "--note", "x", "--category", "chair"])
    assert (args.warmup_steps, args.note, args.category, args.lr) == (50, "x", "chair", None)


def test_help_needs_no_torch():
    code = ("import sys\n"
            "class B:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'torch' or name.startswith('torch.'):\n"
            "            raise ImportError('torch is blocked')\n"
            "sys.meta_path.insert(0, B())\n"
            "from equipose.cli import main\n"
            "try:\n"
            "    main(['train', '--help'])\n"
            "except SystemExit as e:\n"
            "    assert e.code == 0\n"
            "assert 'torch' not in sys.modules\n"
            "print('OK')\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and "--view-weight" in p.stdout and p.stdout.rstrip().endswith("OK"), p.stderr
