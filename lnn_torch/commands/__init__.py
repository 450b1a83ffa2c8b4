"""The ``lnn-torch`` commands that are not Lightning's: one module each, with ``main(argv) -> int``
(``lnn_torch.cli`` dispatches to them)."""
