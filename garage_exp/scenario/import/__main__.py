from garage_exp.scenario.xosc_import import cli

if __name__ == "__main__":
    cli()
