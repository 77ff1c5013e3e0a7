"""The shell: everything a person (or a script) types, and everything shown back.

Only this package and ``cli`` import prompt_toolkit or rich.
"""
