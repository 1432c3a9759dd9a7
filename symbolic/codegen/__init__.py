"""softpinn.symbolic.codegen._codegen"""
