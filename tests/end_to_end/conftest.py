"""Every test in this folder belongs to the slow tier (``pytest -m slow``; CI runs both tiers)."""
from tests.helpers import slow_folder

pytest_collection_modifyitems = slow_folder(__file__)
