"""``equipose demo``: placeholder until the SDK runtime lands."""


def add_arguments(p):
    p.add_argument("--out", default="runs/demo")


def run(args) -> int:
    print("equipose demo: the SDK runtime (depth → pose) is not built yet; "
          "see 'equipose model-info --preset paper' for the model that exists so far.")
    return 0
