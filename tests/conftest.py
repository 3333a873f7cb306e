"""Shared test fixtures: where the real ILC data lives (../shared beside the checkout)."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ILC_SITE1 = REPO.parent / "shared" / "data" / "ilc20" / "site1"


@pytest.fixture(scope="session")
def ilc_site1() -> Path:
    if not ILC_SITE1.is_dir():
        pytest.fail(f"real data missing: {ILC_SITE1} (../shared must sit beside the checkout)")
    return ILC_SITE1
IPIN2023 = REPO.parent / "shared" / "data" / "ipin2023"


@pytest.fixture(scope="session")
def ipin2023() -> Path:
    if not (IPIN2023 / "logs").is_dir():
        pytest.skip(f"IPIN 2023 data absent: {IPIN2023} (../shared must sit beside the checkout)")
    return IPIN2023
