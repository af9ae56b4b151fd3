"""Static publications: a publication's bundle options, its latest build (status, progress, the
manifest of the last finished one) and whether it allows the live mode.

Revision ID: 0006
Revises: 0005
"""
import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("publications") as b:
        b.add_column(sa.Column("live", sa.Boolean, nullable=False, server_default=sa.false()))
        b.add_column(sa.Column("bundle", sa.JSON, nullable=True))
        b.add_column(sa.Column("build", sa.JSON, nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("publications") as b:
        b.drop_column("build")
        b.drop_column("bundle")
        b.drop_column("live")
