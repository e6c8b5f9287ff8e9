import sys

from iscc_gym.train.train import console

if __name__ == "__main__":
    sys.exit(console(None, "python -m train"))
