"""The README's commands and Python snippet stay true."""

import re
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_ci_runs_the_readme_test_command():
    blocks = re.findall(r"```bash\n(.*?)\n```", README, re.S)
    test_cmd = next(b for b in blocks if "pytest" in b and "venv" in b)
    assert test_cmd.strip() in (ROOT / ".ci" / "run").read_text()


def test_python_snippet_runs(tmp_path, monkeypatch):
    from lnn_torch import LNNModule

    snippet = re.search(r"<!-- snippet -->\n```python\n(.*?)\n```", README, re.S).group(1)
    assert len(snippet.strip().splitlines()) <= 6
    model = LNNModule(hidden_dims=[16, 16])
    model.model.normalizer.fit(torch.randn(50, 2), torch.randn(50, 2), torch.randn(50, 2), torch.rand(10, 4) + 0.5)
    model.normalizer_fitted.fill_(True)
    ckpt = tmp_path / "lightning_logs" / "version_0" / "checkpoints" / "last.ckpt"
    ckpt.parent.mkdir(parents=True)
    import lightning as L

    trainer = L.Trainer(max_epochs=0, logger=False, enable_checkpointing=False, enable_progress_bar=False)
    trainer.strategy.connect(model)
    trainer.save_checkpoint(ckpt)
    monkeypatch.chdir(tmp_path)
    scope = {}
    exec(snippet, scope)
    assert scope["q"].shape[0] == 1 and scope["q"].shape[-1] == 2 and torch.isfinite(scope["q"]).all()
