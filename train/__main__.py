from iscc_gym.train.train import cli

if __name__ == "__main__":
    cli()
