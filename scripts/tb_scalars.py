"""Print the scalars of a TensorBoard run: python scripts/tb_scalars.py lightning_logs/version_0 [TAG ...]"""

import argparse

from _common import HelpFormatter


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("run", help="a TensorBoard run folder, e.g. lightning_logs/version_0")
    ap.add_argument("tags", nargs="*", metavar="TAG", help="scalars to print (default: every val/ and test/ scalar)")
    args = ap.parse_args()
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(args.run, size_guidance={"scalars": 0})
    acc.Reload()
    tags = args.tags or [t for t in acc.Tags()["scalars"] if t.startswith(("val/", "test/"))]
    for tag in tags:
        events = acc.Scalars(tag)
        print(f"{tag}: " + ", ".join(f"{e.step}:{e.value:.4g}" for e in events[-8:]))


if __name__ == "__main__":
    main()
