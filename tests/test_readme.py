"""README.md's two set-up commands are exactly what CI runs, and its CLI table is real."""

from __future__ import annotations

import re
from pathlib import Path

from hybridfit.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```bash\n(.*?)```", text, re.S).group(1)
    return [line for line in block.splitlines() if line.strip()]


def test_readme_starts_with_install_and_test_commands():
    install, test = readme_commands()
    assert install.startswith('pip install -e ".[all,test]"') and test == "python -m pytest"  # [all]: every extra


def test_ci_runs_the_readme_commands_in_order():
    ci = [line for line in (ROOT / ".ci/run").read_text().splitlines() if line and not line.startswith(("#", "set ", "cd "))]
    assert ci == readme_commands()


def test_every_command_in_the_readme_table_exists():
    text = (ROOT / "README.md").read_text()
    documented = set(re.findall(r"^\| `hybridfit ([a-z-]+)", text, re.M))
    parser = build_parser()
    commands = set(parser._subparsers._group_actions[0].choices)
    assert documented and documented <= commands, documented - commands


def test_the_folder_tree_names_every_module():
    """Every module of the package (the CLI's subcommands aside) is named in the README's tree."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    text = (root / "README.md").read_text()
    tree = text[text.index("## The folder tree is the architecture"):text.index("## Command line")]
    words = set(re.findall(r"[a-z_0-9]+", tree.lower()))
    modules = [p for p in (root / "hybridfit").rglob("*.py")
               if p.stem not in ("__init__", "__main__") and "cli" not in p.parts]
    missing = sorted(str(p.relative_to(root)) for p in modules if p.stem not in words)
    assert not missing, f"modules missing from the README's folder tree: {missing}"
    packages = sorted({p.parent.name for p in modules} - {"hybridfit"})
    assert all(f"{name}/" in tree for name in packages)
