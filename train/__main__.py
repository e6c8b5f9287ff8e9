import sys

from iscc_gym.train.cli import console

if __name__ == "__main__":
    sys.exit(console(None, "python -m train"))
