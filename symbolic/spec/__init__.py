"""softpinn.symbolic.spec._spec"""
