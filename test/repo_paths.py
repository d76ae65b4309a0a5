"""Where the tests find the repository and their data, from any folder of test/."""
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TEST_DATA = REPO / 'test' / 'data'
