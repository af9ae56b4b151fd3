"""Design versions get a name (the designer's label) and a thumbnail (a small JPEG of the frame
they were saved from, in the blob store).

Revision ID: 0005
Revises: 0004
"""
import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("material_versions") as b:
        b.add_column(sa.Column("name", sa.String(255), nullable=False, server_default=""))
        b.add_column(sa.Column("thumbnail_sha256", sa.String(64), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("material_versions") as b:
        b.drop_column("thumbnail_sha256")
        b.drop_column("name")
