from garage_exp.openscenario.xosc_import import cli

if __name__ == "__main__":
    cli()
