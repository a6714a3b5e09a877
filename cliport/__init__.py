"""CLIPort and Transporter Networks on a PyBullet rebuild of the Ravens tabletop tasks."""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.metadata
import importlib.util
import os
import sys
import tomllib
from collections.abc import Sequence
from types import ModuleType


def _version() -> str:
    """The installed distribution's version (pyproject.toml's ``version``, the one place it is written)."""
    try:
        return importlib.metadata.version("cliport")
    except importlib.metadata.PackageNotFoundError:
        # Not installed: a bare source tree put on sys.path. Read the same number from the checkout's
        # pyproject.toml, or say it is unknown (a PEP 440 local version, never equal to a release).
        pyproject = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "pyproject.toml")
        try:
            with open(pyproject, "rb") as f:
                return str(tomllib.load(f)["project"]["version"])
        except (OSError, KeyError, tomllib.TOMLDecodeError):
            return "0+unknown"


__version__ = _version()

# Folders of the repository root that are installed as subpackages (pyproject.toml's package-dir).
CHECKOUT_SUBPACKAGES = ("tasks", "configs")


class _CheckoutFinder(importlib.abc.MetaPathFinder):
    """Finds ``cliport.tasks`` and ``cliport.configs`` in a source checkout's root folder.

    An installed package holds them inside ``cliport/``; a checkout keeps them next to it. When this
    ``cliport`` is the checkout's (run from the repository root, or without installing), the two names
    resolve to the checkout's folders, so code and tasks always come from the same tree.
    """

    def __init__(self, locations: dict[str, str]) -> None:
        self.locations = locations

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        folder = self.locations.get(fullname)
        if folder is None:
            return None
        return importlib.util.spec_from_file_location(
            fullname, os.path.join(folder, "__init__.py"), submodule_search_locations=[folder]
        )


def checkout_locations(package_dir: str) -> dict[str, str]:
    """Module name -> folder for the subpackages that live beside ``package_dir`` rather than in it.

    Empty for an installed package; for a checkout (a ``pyproject.toml`` beside ``package_dir``) the
    root folders ``tasks/`` and ``configs/``.
    """
    root = os.path.dirname(package_dir)
    if not os.path.isfile(os.path.join(root, "pyproject.toml")):
        return {}
    return {
        f"{__name__}.{name}": os.path.join(root, name)
        for name in CHECKOUT_SUBPACKAGES
        if not os.path.isdir(os.path.join(package_dir, name))
        and os.path.isfile(os.path.join(root, name, "__init__.py"))
    }


def _install_checkout_finder() -> None:
    locations = checkout_locations(os.path.dirname(os.path.abspath(__file__)))
    if locations and not any(isinstance(f, _CheckoutFinder) for f in sys.meta_path):
        # First in line: an editable install of another checkout must not supply this one's tasks.
        sys.meta_path.insert(0, _CheckoutFinder(locations))


_install_checkout_finder()


def _register_gymnasium_envs() -> None:
    # Only gymnasium is imported here: the environments load the simulator when gymnasium.make builds one.
    from cliport.gym_registration import register_envs

    register_envs()


_register_gymnasium_envs()
