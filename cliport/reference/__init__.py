"""Published results of the CLIPort and Transporter Networks papers, shipped with the package."""
