"""Print the scalars of a TensorBoard run: python scripts/tb_scalars.py lightning_logs/version_0 [TAG ...]"""

import sys

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator


def main() -> None:
    run = sys.argv[1]
    acc = EventAccumulator(run, size_guidance={"scalars": 0})
    acc.Reload()
    tags = sys.argv[2:] or [t for t in acc.Tags()["scalars"] if t.startswith(("val/", "test/"))]
    for tag in tags:
        events = acc.Scalars(tag)
        print(f"{tag}: " + ", ".join(f"{e.step}:{e.value:.4g}" for e in events[-8:]))


if __name__ == "__main__":
    main()
